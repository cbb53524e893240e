"""Zenoh session factory: one place that turns :class:`ZenohSettings` into an open session, and one place that
asks every queryable for its answer."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import socket
import threading
import time
from types import FrameType
from typing import Any

import zenoh

from .errors import ConnectError, StartupError
from .settings import ZenohSettings


def zenoh_config(settings: ZenohSettings) -> zenoh.Config:
    cfg = zenoh.Config.from_file(str(settings.config_file)) if settings.config_file else zenoh.Config()
    cfg.insert_json5("mode", json.dumps(settings.mode))
    if settings.connect:
        _insert_endpoints(cfg, "connect", settings.connect)
        if settings.mode != "router":
            # keep retrying the endpoints for the configured time, so a process may start before its router
            timeout_ms = -1 if settings.connect_timeout_s < 0 else round(settings.connect_timeout_s * 1000)
            cfg.insert_json5("connect/timeout_ms", json.dumps(timeout_ms))
    if settings.listen:
        _insert_endpoints(cfg, "listen", settings.listen)
    cfg.insert_json5("scouting/multicast/enabled", json.dumps(settings.multicast_scouting))
    if settings.block_close_s is not None:
        cfg.insert_json5(
            "transport/link/tx/queue/congestion_control/block/wait_before_close",
            json.dumps(round(settings.block_close_s * 1e6)),
        )
    # lossless delivery over sockets; see ZenohSettings.shared_memory for why the implicit SHM path is off
    cfg.insert_json5("transport/shared_memory/enabled", json.dumps(settings.shared_memory))
    _insert_tls(cfg, settings)
    return cfg


def _insert_endpoints(cfg: zenoh.Config, which: str, endpoints: list[str]) -> None:
    """``connect``/``listen`` endpoints; one that Zenoh cannot parse is a :class:`ConnectError` saying so (not,
    later, "no router reachable")."""
    try:
        cfg.insert_json5(f"{which}/endpoints", json.dumps(endpoints))
    except zenoh.ZError as exc:
        found = re.search(r'msg: "(.*?) at /', str(exc))
        why = found.group(1) if found else _first_line(exc)
        variable = "FIXSTREAM_ZENOH_CONNECT" if which == "connect" else "FIXSTREAM_ZENOH_LISTEN"
        raise ConnectError(
            f"invalid Zenoh {which} endpoint in {', '.join(endpoints)} ({why}; set it with --{which} or {variable})"
        ) from None


def _insert_tls(cfg: zenoh.Config, settings: ZenohSettings) -> None:
    """Mutual TLS: the CA that every side checks the other against, and this process's certificate, used to
    listen (a router) and to connect (every process); the certificate's common name is the identity the router's
    access-control rules know it by."""
    if settings.tls_root_ca is None and settings.tls_cert is None:
        return
    if settings.tls_root_ca is None or settings.tls_cert is None or settings.tls_key is None:
        raise ConnectError(
            "TLS needs FIXSTREAM_ZENOH_TLS_ROOT_CA, FIXSTREAM_ZENOH_TLS_CERT and FIXSTREAM_ZENOH_TLS_KEY together"
        )
    for path in (settings.tls_root_ca, settings.tls_cert, settings.tls_key):
        if not path.is_file():
            raise ConnectError(f"TLS file not found: {path}")
        if not os.access(path, os.R_OK):  # else Zenoh reports only "no router reachable" after the connect timeout
            raise ConnectError(f"TLS file not readable by this user (uid {os.getuid()}): {path}")
    tls = {
        "root_ca_certificate": str(settings.tls_root_ca),
        "enable_mtls": True,
        "connect_certificate": str(settings.tls_cert),
        "connect_private_key": str(settings.tls_key),
    }
    if settings.mode == "router" or settings.listen:
        tls |= {"listen_certificate": str(settings.tls_cert), "listen_private_key": str(settings.tls_key)}
    for name, value in tls.items():
        cfg.insert_json5(f"transport/link/tls/{name}", json.dumps(value))


def open_session(settings: ZenohSettings | None = None, *, take_signals: bool = True) -> zenoh.Session:
    """An open session, or :class:`ConnectError` (one line, the endpoints and the variable that sets them).

    ``zenoh.open`` blocks in Rust for up to the connect timeout (forever at -1), where Python runs no signal
    handler: it runs on a daemon thread while the calling thread waits in short slices. Called from the main
    thread, SIGINT and SIGTERM during that wait stop the process at once: SIGINT raises ``KeyboardInterrupt`` (exit
    130), SIGTERM ``SystemExit(143)`` (128 + the signal); the handlers in place before are restored either way.
    ``take_signals=False`` leaves the caller's handlers in place (they run between the slices): for a caller that
    must stop in its own way, e.g. the stack runner, which stops its processes first."""
    settings = settings or ZenohSettings()
    cfg = zenoh_config(settings)
    try:
        return _open_interruptible(cfg, take_signals)
    except zenoh.ZError as exc:
        where = ", ".join(settings.connect or settings.listen) or "(no endpoint)"
        if settings.mode == "router" or not settings.connect:
            raise ConnectError(f"cannot open a Zenoh {settings.mode} session on {where}: {_first_line(exc)}") from None
        waited = "one attempt" if settings.connect_timeout_s == 0 else f"{settings.connect_timeout_s:g} s"
        raise ConnectError(
            f"no Zenoh router reachable at {where} (tried for {waited}; set the endpoint with --connect or "
            "FIXSTREAM_ZENOH_CONNECT, the wait with FIXSTREAM_ZENOH_CONNECT_TIMEOUT_S)"
        ) from None


#: how often the thread waiting for zenoh.open looks at signals, s
_OPEN_SLICE_S = 0.05


def _open_interruptible(cfg: zenoh.Config, take_signals: bool) -> zenoh.Session:
    """``zenoh.open(cfg)`` on a daemon thread; see :func:`open_session` for the signals."""
    outcome: list[Any] = []
    abandoned = threading.Event()

    def opener() -> None:
        try:
            session = zenoh.open(cfg)
        except BaseException as exc:  # handed to the waiting thread
            outcome.append(exc)
            return
        if abandoned.is_set():  # the caller was interrupted meanwhile: nobody will use or close it
            with contextlib.suppress(Exception):
                session.close()
            return
        outcome.append(session)

    thread = threading.Thread(target=opener, name="zenoh-open", daemon=True)
    received: list[int] = []
    previous: dict[int, Any] = {}
    if take_signals and threading.current_thread() is threading.main_thread():

        def on_signal(signum: int, _frame: FrameType | None) -> None:
            received.append(signum)

        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, on_signal)
    try:
        thread.start()
        while thread.is_alive() and not received:
            thread.join(_OPEN_SLICE_S)
    finally:
        for number, handler in previous.items():
            signal.signal(number, signal.SIG_DFL if handler is None else handler)  # None: set outside Python
    if received and not outcome:
        abandoned.set()
        raise _interrupted(received[0])
    result = outcome[0]
    if isinstance(result, BaseException):
        raise result
    if received:  # opened in the same slice as the signal: close it and stop as asked
        with contextlib.suppress(Exception):
            result.close()
        raise _interrupted(received[0])
    session: zenoh.Session = result
    return session


def _interrupted(signum: int) -> BaseException:
    """What a signal during :func:`open_session` raises: Ctrl-C as everywhere (exit 130), else 128 + the signal."""
    return KeyboardInterrupt() if signum == signal.SIGINT else SystemExit(128 + signum)


def query_all(session: zenoh.Session, selector: str, timeout_s: float) -> list[zenoh.Reply]:
    """Every reply of every matching queryable: target ALL and no consolidation. (Zenoh's default consolidation
    keeps one reply per key, so queryables that answer on the query's own wildcard key would hide each other.)"""
    return list(
        session.get(
            selector,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=timeout_s,
        )
    )


def refuse_namesake(session: zenoh.Session, token_key: str, wait_s: float, stop: threading.Event | None = None) -> None:
    """:class:`StartupError` if another process already holds the liveliness token ``token_key`` (the same service
    and instance) and still holds it after ``wait_s``. Two processes with one name publish one source with two seq
    counters: every consumer counts thousands of messages lost (a new user's audit: ``lost: 6035``) and ``fixstream
    status`` shows the name twice. The wait lets a restarted process start while its crashed predecessor's token is
    still on its way out (a killed process's link closes at once; a vanished host's within Zenoh's lease, 10 s).
    Returns early once ``stop`` is set (SIGTERM during the wait). Needs a router: a peer that has not yet found its
    peers sees no token."""
    deadline = time.monotonic() + wait_s
    while stop is None or not stop.is_set():
        holders = [r for r in session.liveliness().get(token_key, timeout=1.0) if r.ok is not None]
        if not holders:
            return
        if time.monotonic() >= deadline:
            raise StartupError(
                f"another process is already alive as {token_key} (waited {wait_s:g} s for it to go); give this one"
                " another instance name"
            )
        if stop is not None:
            stop.wait(0.5)
        else:
            time.sleep(0.5)


def _first_line(exc: BaseException) -> str:
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free a moment ago on ``host`` (for loopback test stacks)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def port_free(port: int, host: str = "127.0.0.1") -> bool:
    """Whether a listener can bind ``port`` on ``host`` now (nobody listens there). With ``SO_REUSEADDR``, as the
    Zenoh router binds: connections of a stopped stack in TIME_WAIT do not make the port busy."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
        return True
