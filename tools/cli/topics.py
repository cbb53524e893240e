"""``fixstream topics``: the keys that carry messages now, with their message type and rate (``ros2 topic list -v``).

Subscribes to ``--key`` (default ``fixstream/**``) for ``--duration`` seconds and prints one line per key that
carried a message meanwhile: key, message type (the model named in the Zenoh encoding), messages seen, the rate
(Hz, (n − 1) over the span of their receive times, as ``fixstream hz`` computes it), and the publishers
(``header.source``) seen. A key whose publisher is silent during the window is not listed: services that are up
but idle show in ``fixstream status``. ``--json`` prints one JSON object per key instead.

Exit status: 0 when at least one key carried a message, 3 when none did within ``--duration``, 2 for a bad key
expression or an unreachable router.
"""

from __future__ import annotations

import argparse
from typing import Any

from .common import add_zenoh_arguments, key_expr, seconds


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--key", type=key_expr, default="fixstream/**", help="key expression to listen on")
    parser.add_argument("--duration", type=seconds, default=2.0, help="seconds to listen before printing")
    parser.add_argument("--json", action="store_true", help="one JSON object per key")
    add_zenoh_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import json
    import sys
    from collections import Counter

    from shared import codec

    from . import exit_codes
    from .listen import Listener, schema_of
    from .rates import IntervalStats

    if args.duration <= 0:
        print("fixstream topics: --duration must be > 0", file=sys.stderr)
        return exit_codes.USAGE
    stats: dict[str, IntervalStats] = {}
    types: dict[str, Counter[str]] = {}
    sources: dict[str, set[str]] = {}
    with Listener(args, args.key) as listener:
        for sample in listener.samples(args.duration):
            stats.setdefault(sample.key, IntervalStats()).add(sample.rx_ns)
            types.setdefault(sample.key, Counter())[schema_of(sample.encoding)] += 1
            header = codec.peek_header(sample.payload)
            if header is not None:
                sources.setdefault(sample.key, set()).add(header[0])
    if not stats:
        print(f"fixstream topics: no message on {args.key} in {args.duration:g} s", file=sys.stderr)
        return exit_codes.TIMEOUT
    rows: list[dict[str, Any]] = []
    for key in sorted(stats):
        summary = stats[key].summary()
        rows.append(
            {
                "key": key,
                "type": "|".join(t for t, _ in types[key].most_common()),
                "messages": stats[key].messages,
                "rate_hz": None if summary is None else round(summary.rate_hz, 3),
                "sources": sorted(sources.get(key, ())),
            }
        )
    if args.json:
        for row in rows:
            print(json.dumps(row))
        return exit_codes.OK
    width = max(len(r["key"]) for r in rows)
    type_width = max(len("type"), *(len(r["type"]) for r in rows))
    print(f"{'key':{width}}  {'type':{type_width}}  {'messages':>8}  {'rate Hz':>9}  publishers")
    for r in rows:
        rate = "-" if r["rate_hz"] is None else f"{r['rate_hz']:.2f}"
        print(f"{r['key']:{width}}  {r['type']:{type_width}}  {r['messages']:8d}  {rate:>9}  {', '.join(r['sources'])}")
    return exit_codes.OK
