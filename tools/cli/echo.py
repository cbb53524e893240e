"""``fixstream echo KEYEXPR``: print every message on a key expression, decoded, one line each."""

from __future__ import annotations

import argparse

from .common import add_zenoh_arguments, key_expr


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("key_expr", nargs="?", default="fixstream/**", type=key_expr)
    parser.add_argument("--json", action="store_true", help="one JSON object per line (key, schema, message)")
    parser.add_argument("--count", type=int, default=0, help="exit after this many messages (0: forever)")
    parser.add_argument("--timeout", type=float, default=0.0, help="exit after this many seconds (0: never)")
    add_zenoh_arguments(parser)


def format_line(key: str, payload: bytes, encoding: str, as_json: bool) -> str:
    import json

    from shared import codec

    try:
        msg = codec.decode(payload, encoding)
    except codec.DecodeError as exc:
        if as_json:
            return json.dumps({"key": key, "error": exc.reason, "detail": exc.detail})
        return f"{key} !! {exc.reason}: {exc.detail}"
    if as_json:
        return json.dumps({"key": key, "schema": type(msg).__name__, "message": msg.model_dump(mode="json")})
    body = msg.model_dump_json(exclude={"header"})
    return f"{key} [{type(msg).__name__} t={msg.header.stamp_ns * 1e-9:.3f}s seq={msg.header.seq}] {body}"


def run(args: argparse.Namespace) -> int:
    import queue
    import signal
    import time

    from shared.session import open_session

    from .common import zenoh_settings_from

    lines: queue.Queue[str] = queue.Queue()
    session = open_session(zenoh_settings_from(args))
    sub = session.declare_subscriber(
        args.key_expr,
        lambda s: lines.put(format_line(str(s.key_expr), s.payload.to_bytes(), str(s.encoding), args.json)),
    )
    stop = {"flag": False}
    signal.signal(signal.SIGTERM, lambda *_: stop.update(flag=True))
    deadline = time.monotonic() + args.timeout if args.timeout > 0 else float("inf")
    printed = 0
    try:
        while not stop["flag"] and time.monotonic() < deadline:
            try:
                line = lines.get(timeout=0.1)
            except queue.Empty:
                continue
            print(line, flush=True)
            printed += 1
            if args.count and printed >= args.count:
                break
    finally:
        sub.undeclare()
        session.close()
    return 0
