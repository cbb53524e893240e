"""Zenoh session factory: one place that turns :class:`ZenohSettings` into an open session, and one place that
asks every queryable for its answer."""

from __future__ import annotations

import json
import socket

import zenoh

from .errors import ConnectError
from .settings import ZenohSettings


def zenoh_config(settings: ZenohSettings) -> zenoh.Config:
    cfg = zenoh.Config.from_file(str(settings.config_file)) if settings.config_file else zenoh.Config()
    cfg.insert_json5("mode", json.dumps(settings.mode))
    if settings.connect:
        cfg.insert_json5("connect/endpoints", json.dumps(settings.connect))
        if settings.mode != "router":
            # keep retrying the endpoints for the configured time, so a process may start before its router
            timeout_ms = -1 if settings.connect_timeout_s < 0 else round(settings.connect_timeout_s * 1000)
            cfg.insert_json5("connect/timeout_ms", json.dumps(timeout_ms))
    if settings.listen:
        cfg.insert_json5("listen/endpoints", json.dumps(settings.listen))
    cfg.insert_json5("scouting/multicast/enabled", json.dumps(settings.multicast_scouting))
    return cfg


def open_session(settings: ZenohSettings | None = None) -> zenoh.Session:
    """An open session, or :class:`ConnectError` (one line, the endpoints and the variable that sets them)."""
    settings = settings or ZenohSettings()
    try:
        return zenoh.open(zenoh_config(settings))
    except zenoh.ZError as exc:
        where = ", ".join(settings.connect or settings.listen) or "(no endpoint)"
        if settings.mode == "router" or not settings.connect:
            raise ConnectError(f"cannot open a Zenoh {settings.mode} session on {where}: {_first_line(exc)}") from None
        waited = "one attempt" if settings.connect_timeout_s == 0 else f"{settings.connect_timeout_s:g} s"
        raise ConnectError(
            f"no Zenoh router reachable at {where} (tried for {waited}; set the endpoint with --connect or "
            "FIXSTREAM_ZENOH_CONNECT, the wait with FIXSTREAM_ZENOH_CONNECT_TIMEOUT_S)"
        ) from None


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


def _first_line(exc: BaseException) -> str:
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free a moment ago on ``host`` (for loopback test stacks)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def port_free(port: int, host: str = "127.0.0.1") -> bool:
    """Whether ``port`` can be bound on ``host`` now (nobody listens there)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
        return True
