"""Arguments shared by the client commands: how to reach Zenoh."""

from __future__ import annotations

import argparse

from ..settings import ZenohSettings


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("zenoh")
    g.add_argument("--connect", action="append", help="endpoint to connect to (repeatable); default from env")
    g.add_argument("--listen", action="append", help="endpoint to listen on (repeatable)")
    g.add_argument("--mode", choices=["client", "peer", "router"], help="session mode; default from env")


def zenoh_settings_from(args: argparse.Namespace) -> ZenohSettings:
    overrides: dict[str, object] = {}
    if getattr(args, "connect", None):
        overrides["connect"] = args.connect
    if getattr(args, "listen", None):
        overrides["listen"] = args.listen
    if getattr(args, "mode", None):
        overrides["mode"] = args.mode
    base = ZenohSettings()
    return base.model_copy(update=overrides)
