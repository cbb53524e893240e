"""What the live services of a stack say about themselves: their liveliness tokens and status documents.

Every fixstream service declares ``fixstream/alive/<service>/<instance>`` (a liveliness token) and answers
``fixstream/status/<service>/<instance>`` with a JSON document (:meth:`shared.service.Service.status`). The recorder
asks them all when a run starts (its metadata), and ``fixstream up`` asks them after its driver ends, to stop the
stack only once it has settled (:func:`quiet_counts`).
"""

from __future__ import annotations

import contextlib
import json
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import zenoh

from . import keys
from .service import PLAYER_PREFIX
from .session import query_all

#: status queries a start marker makes at most, until every live service has answered
STATUS_ATTEMPTS = 3


class AliveTokens:
    """The ``fixstream/alive/**`` tokens alive, as ``<service>/<instance>``, kept by a liveliness subscriber (with
    history: the tokens declared before it too)."""

    def __init__(self) -> None:
        self._alive: set[str] = set()
        self._lock = threading.Lock()

    def watch(self, session: zenoh.Session) -> Any:
        """Start tracking on ``session``; returns the subscriber (to undeclare)."""
        return session.liveliness().declare_subscriber(keys.ALIVE_ALL, self._on_sample, history=True)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            who = "/".join(keys.parse_alive(str(sample.key_expr)))
        except ValueError:
            return
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(who)
            else:
                self._alive.discard(who)

    def now(self) -> set[str]:
        with self._lock:
            return set(self._alive)


def owner(doc: Mapping[str, Any]) -> str:
    """``<service>/<instance>`` of a status document."""
    return f"{doc.get('service', '?')}/{doc.get('instance', '?')}"


def alive_services(session: zenoh.Session, timeout_s: float) -> set[str]:
    """The ``<service>/<instance>`` of every ``fixstream/alive/**`` liveliness token a query finds within
    ``timeout_s`` (players' included; empty if the query fails)."""
    alive: set[str] = set()
    with contextlib.suppress(Exception):
        for reply in session.liveliness().get(keys.ALIVE_ALL, timeout=timeout_s):
            if reply.ok is not None:
                with contextlib.suppress(ValueError):
                    alive.add("/".join(keys.parse_alive(str(reply.ok.key_expr))))
    return alive


def collect_statuses(
    session: zenoh.Session,
    timeout_s: float,
    alive_now: Callable[[], set[str]] | None = None,
    attempts: int = STATUS_ATTEMPTS,
) -> tuple[list[dict[str, Any]], list[str]]:
    """Every live service's status and the liveliness tokens alive (``<service>/<instance>``: those ``alive_now``
    knows, and those a liveliness query finds; a player's are not counted, it has no status queryable): the status
    query is repeated (at most ``attempts`` times, each waiting ``timeout_s``) until every service with
    a token has answered, so a service slow to answer under load is not missing from the recording's metadata."""
    answered: dict[str, dict[str, Any]] = {}
    alive: set[str] = set()
    for _ in range(attempts):
        if alive_now is not None:
            alive |= alive_now()
        alive |= alive_services(session, timeout_s)
        with contextlib.suppress(Exception):
            for reply in query_all(session, keys.STATUS_ALL, timeout_s):
                if reply.ok is not None:
                    with contextlib.suppress(ValueError):
                        doc = json.loads(reply.ok.payload.to_bytes())
                        if isinstance(doc, dict):
                            answered[owner(doc)] = doc
        alive = {a for a in alive if not a.startswith(PLAYER_PREFIX)}  # a player's token has no status queryable
        if alive <= answered.keys():
            break
    return list(answered.values()), sorted(alive)


def quiet_counts(statuses: Sequence[Mapping[str, Any]], expected: Iterable[str]) -> dict[str, int] | None:
    """Each answering service's count of samples received (``<service>/<instance>``), when every service in
    ``expected`` answered and every answer has an empty inbox and no run end pending; else None (the stack is still
    busy, or an expected service did not answer). Two equal results a moment apart mean nothing arrived in
    between: the stack has settled."""
    counts: dict[str, int] = {}
    for doc in statuses:
        who = owner(doc)
        scenario = doc.get("scenario")
        counters = doc.get("counters")
        if doc.get("queue_depth") != 0 or not isinstance(counters, dict):
            return None
        if isinstance(scenario, dict) and scenario.get("end_pending"):
            return None
        counts[who] = int(counters.get("received", 0))
    if not set(expected) <= counts.keys():
        return None
    return counts
