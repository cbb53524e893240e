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
    import sys

    import zenoh

    from shared import keys
    from shared.service import PLAYER_PREFIX
    from shared.session import open_session, query_all
    from shared.status import alive_services, owner

    from . import exit_codes
    from .common import zenoh_settings_from

    session = open_session(zenoh_settings_from(args))
    try:
        replies = query_all(session, args.selector, args.timeout)
        alive = alive_services(session, args.timeout)
    finally:
        session.close()
    bodies: list[dict[str, Any]] = []
    for reply in replies:  # an error reply on stderr: stdout stays what --json promises, one JSON object a line
        if reply.ok is None:
            print(
                f"fixstream status: an error reply: {reply.err.payload.to_string() if reply.err else 'unknown'}",
                file=sys.stderr,
            )
            continue
        bodies.append(json.loads(reply.ok.payload.to_bytes()))
    # a service alive (its token) under the selector that did not answer (stopped, stalled) is named, not left out
    selector = zenoh.KeyExpr(args.selector)
    answered = {owner(b) for b in bodies}
    silent = sorted(
        who
        for who in alive
        if not who.startswith(PLAYER_PREFIX)  # a player has no status queryable
        and who not in answered
        and selector.intersects(zenoh.KeyExpr(keys.status(*who.split("/", 1))))
    )
    if silent:
        print(f"fixstream status: alive but no answer within {args.timeout:g} s: {', '.join(silent)}", file=sys.stderr)
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
