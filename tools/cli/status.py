"""``fixstream status [SELECTOR]``: ask the services' status queryables and print every answer.

SELECTOR is ``SERVICE`` (every instance of it), ``SERVICE/INSTANCE`` (e.g. ``lbl_nav/lbl1``) or a key expression
under ``fixstream/status/`` (e.g. ``fixstream/status/*/default``); default: every service.

Exit status: 0 when at least one service answered, 3 when none did within ``--timeout``, 2 for a bad selector or
an unreachable router.
"""

from __future__ import annotations

import argparse
from typing import Any

from .common import add_zenoh_arguments, key_expr, seconds


def selector(text: str) -> str:
    """argparse ``type=``: ``SERVICE``, ``SERVICE/INSTANCE`` or a key expression (``fixstream/...``) -> the key
    expression of the status queryables it names."""
    from shared import keys

    if text == keys.ROOT or text.startswith(keys.ROOT + "/"):
        return key_expr(text)
    parts = text.split("/")
    if len(parts) > 2 or not all(parts):
        raise argparse.ArgumentTypeError(
            f"not a status selector: {text!r} (SERVICE, SERVICE/INSTANCE or a key expression fixstream/status/...)"
        )
    return key_expr("/".join([keys.STATUS_ALL.removesuffix("/**"), *parts, *(["*"] if len(parts) == 1 else [])]))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "selector",
        nargs="?",
        default="fixstream/status/**",
        type=selector,
        help="SERVICE (every instance), SERVICE/INSTANCE (e.g. lbl_nav/lbl1) or a key expression such as"
        " fixstream/status/*/default (default: every service)",
    )
    parser.add_argument("--timeout", type=seconds, default=2.0, help="seconds to wait for replies")
    parser.add_argument("--json", action="store_true", help="print the raw JSON replies, one per line")
    add_zenoh_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import json

    from shared.session import open_session, query_all

    from . import exit_codes
    from .common import zenoh_settings_from

    session = open_session(zenoh_settings_from(args))
    try:
        replies = query_all(session, args.selector, args.timeout)
    finally:
        session.close()
    bodies: list[dict[str, Any]] = []
    for reply in replies:
        if reply.ok is None:
            print(f"error: {reply.err.payload.to_string() if reply.err else 'unknown'}")
            continue
        bodies.append(json.loads(reply.ok.payload.to_bytes()))
    bodies.sort(key=lambda b: (str(b.get("service")), str(b.get("instance"))))
    for body in bodies:
        if args.json:
            print(json.dumps(body))
            continue
        c = body.get("counters", {})
        print(
            f"{body.get('service')}/{body.get('instance')}: up {body.get('uptime_s')} s, "
            f"received {c.get('received')}, accepted {c.get('accepted')}, rejected {c.get('rejected')}, "
            f"published {c.get('published')}, last error: {c.get('last_error')}"
        )
        for reason, n in sorted(c.get("rejected_by_reason", {}).items()):
            print(f"    {reason}: {n}")
    if not bodies:
        print(f"no service answered on {args.selector}")
        return exit_codes.TIMEOUT
    return exit_codes.OK
