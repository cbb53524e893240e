"""``fixstream router``: a router-mode Zenoh session that runs until SIGTERM/SIGINT."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from pathlib import Path

import zenoh

from shared.session import open_session
from shared.settings import ZenohSettings

from .common import seconds

log = logging.getLogger("fixstream.router")
#: the router's wait before it closes a link whose queue a blocking message cannot enter, s
ROUTER_BLOCK_CLOSE_S = 60.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--listen", action="append", help="endpoint, e.g. tcp/127.0.0.1:7447 (repeatable)")
    parser.add_argument("--connect", action="append", default=[], help="other routers to mesh with")
    parser.add_argument(
        "--config",
        type=Path,
        help="a Zenoh JSON5 configuration to start from (e.g. tools/stack/router-secure.json5: access control);"
        " default: $FIXSTREAM_ZENOH_CONFIG_FILE",
    )
    parser.add_argument(
        "--block-close-s",
        type=seconds,
        default=ROUTER_BLOCK_CLOSE_S,
        help="seconds a blocking message may wait for a slow subscriber's full link before the router closes that"
        " link (Zenoh's default is 5 s: a subscriber busy for 5 s would lose its session and what was in flight)",
    )


def run(args: argparse.Namespace) -> int:
    env = ZenohSettings()
    listen = args.listen or env.listen or ["tcp/127.0.0.1:7447"]
    settings = env.model_copy(
        update={
            "mode": "router",
            "listen": listen,
            "connect": args.connect,
            "multicast_scouting": False,
            "config_file": args.config or env.config_file,
            "block_close_s": args.block_close_s,
        }
    )
    zenoh.init_log_from_env_or("error")  # RUST_LOG=zenoh=debug shows what the router does (ACL denials, drops)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    session = open_session(settings)
    log.info("router %s listening on %s", session.zid(), ", ".join(listen))
    print(f"router listening on {' '.join(listen)}", flush=True)
    try:
        stop.wait()
    finally:
        # closing can stall while clients are still tearing down their links; never let it block the exit
        closer = threading.Thread(target=session.close, daemon=True)
        closer.start()
        closer.join(timeout=3.0)
    log.info("router stopped")
    if closer.is_alive():
        log.warning("router session close still pending after 3 s; exiting anyway")
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
    return 0
