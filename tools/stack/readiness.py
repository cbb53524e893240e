"""Readiness probes: a TCP port that accepts (the embedded router) and liveliness tokens (services)."""

from __future__ import annotations

import contextlib
import socket
import threading
from typing import Any


def port_open(port: int, host: str = "127.0.0.1", timeout: float = 0.2) -> bool:
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


class LivelinessWatch:
    """A client session on the loopback router that tracks ``fixstream/alive/**`` tokens."""

    def __init__(self, endpoint: str, key_expr: str = "fixstream/alive/**", tls: dict[str, Any] | None = None) -> None:
        self.endpoint = endpoint
        self.key_expr = key_expr
        #: ZenohSettings TLS fields (tls_root_ca, tls_cert, tls_key) for a secure stack
        self.tls = tls or {}
        self._alive: set[str] = set()
        self._lock = threading.Lock()
        #: services that answered a status query of :meth:`quiet_counts` (``<service>/<instance>``)
        self._answered: set[str] = set()
        self._session: Any = None
        self._subscriber: Any = None
        self._zenoh: Any = None

    def open(self) -> None:
        import zenoh

        from shared.session import open_session
        from shared.settings import ZenohSettings

        self._zenoh = zenoh
        # the runner's own SIGINT/SIGTERM handling stays in place: it stops the stack's processes first
        settings = ZenohSettings(mode="client", connect=[self.endpoint], listen=[], **self.tls)
        self._session = open_session(settings, take_signals=False)
        self._subscriber = self._session.liveliness().declare_subscriber(self.key_expr, self._on_sample, history=True)

    def _on_sample(self, sample: Any) -> None:
        key = str(sample.key_expr)
        with self._lock:
            if sample.kind == self._zenoh.SampleKind.PUT:
                self._alive.add(key)
            else:
                self._alive.discard(key)

    def match(self, key_expr: str) -> str | None:
        """An alive token matching ``key_expr`` (wildcards allowed), or None."""
        if self._session is None:
            return None
        ke = self._zenoh.KeyExpr(key_expr)
        with self._lock:
            alive = sorted(self._alive)
        return next((k for k in alive if ke.intersects(self._zenoh.KeyExpr(k))), None)

    def quiet_counts(self, timeout_s: float, expected: set[str] | None = None) -> dict[str, int] | None:
        """:func:`shared.status.quiet_counts` of the stack's services now, expecting an answer from ``expected``
        (``<service>/<instance>``: the stack's own services) and from every live service that answered a status
        query of this watch before (a token with no status queryable, a test probe's, is not waited for). None:
        busy, an expected service silent, or no session."""
        from shared.status import collect_statuses, owner, quiet_counts

        if self._session is None:
            return None
        statuses, alive = collect_statuses(self._session, timeout_s, attempts=1)
        answered = {owner(d) for d in statuses}
        waited = (set(alive) & self._answered) | (expected or set())
        self._answered |= answered
        return quiet_counts(statuses, waited)

    def alive_key(self, key_expr: str) -> str | None:
        """``<service>/<instance>`` of the alive token matching ``key_expr`` (see :meth:`match`), or None."""
        from shared import keys

        key = self.match(key_expr)
        if key is None:
            return None
        try:
            return "/".join(keys.parse_alive(key))
        except ValueError:
            return None

    def close(self) -> None:
        if self._session is None:
            return
        with contextlib.suppress(Exception):
            self._subscriber.undeclare()
        with contextlib.suppress(Exception):
            self._session.close()
        self._session = None
