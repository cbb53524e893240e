"""Zenoh session factory: one place that turns :class:`ZenohSettings` into an open session."""

from __future__ import annotations

import json
import socket

import zenoh

from .settings import ZenohSettings


def zenoh_config(settings: ZenohSettings) -> zenoh.Config:
    cfg = zenoh.Config.from_file(str(settings.config_file)) if settings.config_file else zenoh.Config()
    cfg.insert_json5("mode", json.dumps(settings.mode))
    if settings.connect:
        cfg.insert_json5("connect/endpoints", json.dumps(settings.connect))
    if settings.listen:
        cfg.insert_json5("listen/endpoints", json.dumps(settings.listen))
    cfg.insert_json5("scouting/multicast/enabled", json.dumps(settings.multicast_scouting))
    return cfg


def open_session(settings: ZenohSettings | None = None) -> zenoh.Session:
    return zenoh.open(zenoh_config(settings or ZenohSettings()))


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free a moment ago on ``host`` (for loopback test stacks)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])
