"""``fixstream status``: query every ``fixstream/status/**`` queryable and print the replies."""

from __future__ import annotations

import argparse

from .common import add_zenoh_arguments


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("selector", nargs="?", default="fixstream/status/**")
    parser.add_argument("--timeout", type=float, default=2.0, help="seconds to wait for replies")
    parser.add_argument("--json", action="store_true", help="print the raw JSON replies, one per line")
    add_zenoh_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import json

    from ..session import open_session
    from .common import zenoh_settings_from

    session = open_session(zenoh_settings_from(args))
    try:
        replies = list(session.get(args.selector, timeout=args.timeout))
    finally:
        pass
    found = 0
    for reply in replies:
        if reply.ok is None:
            print(f"error: {reply.err.payload.to_string() if reply.err else 'unknown'}")
            continue
        found += 1
        body = json.loads(reply.ok.payload.to_bytes())
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
    session.close()
    if not found:
        print("no service answered")
        return 1
    return 0
