"""``fixstream hz KEYEXPR``: the message rate on a key expression, like ``ros2 topic hz``.

For every key that matches, over the last ``--window`` intervals between its messages: the mean rate (Hz) and the
minimum, maximum and standard deviation of the intervals (s), printed every ``--interval`` seconds while messages
arrive and once more at the end (Ctrl-C, ``--duration`` or ``--count``). Intervals are measured on the receive
clock (``--clock receive``: what a subscriber here sees) or on the messages' own ``header.stamp_ns``
(``--clock stamp``: the data's rate, whatever the playback ``--rate`` was).

Exit status: 0 when at least one key had two messages (a rate), 3 when none did, 2 for a bad key expression or an
unreachable router.
"""

from __future__ import annotations

import argparse

from .common import add_zenoh_arguments, key_expr, non_negative_int, positive_int, positive_seconds, seconds


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("key_expr", type=key_expr, help="Zenoh key expression, e.g. fixstream/truth/**")
    parser.add_argument("--window", type=positive_int, default=10_000, help="intervals per key the statistics use")
    parser.add_argument(
        "--clock",
        choices=["receive", "stamp"],
        default="receive",
        help="measure intervals between receive times or between header.stamp_ns",
    )
    parser.add_argument("--interval", type=positive_seconds, default=1.0, help="seconds between printed updates")
    parser.add_argument("--duration", type=seconds, default=0.0, help="stop after this many seconds (0: when stopped)")
    parser.add_argument(
        "--count", type=non_negative_int, default=0, help="stop after this many messages in all (0: no limit)"
    )
    parser.add_argument("--json", action="store_true", help="only the final statistics, one JSON object per key")
    add_zenoh_arguments(parser)


def format_line(key: str, s: object) -> str:
    from .rates import RateSummary

    assert isinstance(s, RateSummary)
    return (
        f"{key}: {s.rate_hz:.3f} Hz  min {s.min_s:.4f} s  max {s.max_s:.4f} s  std {s.std_s:.5f} s"
        f"  window {s.intervals}"
    )


def run(args: argparse.Namespace) -> int:
    import json
    import sys
    import time

    from shared import codec

    from . import exit_codes
    from .listen import Listener
    from .rates import IntervalStats

    stats: dict[str, IntervalStats] = {}
    unstamped = 0
    fresh: set[str] = set()
    seen = 0
    next_print = time.monotonic() + args.interval
    with Listener(args, args.key_expr) as listener:
        for sample in listener.samples(args.duration):
            if args.clock == "stamp":
                header = codec.peek_header(sample.payload)
                if header is None:
                    unstamped += 1
                    continue
                t_ns = header[2]
            else:
                t_ns = sample.rx_ns
            stats.setdefault(sample.key, IntervalStats(args.window)).add(t_ns)
            fresh.add(sample.key)
            seen += 1
            if not args.json and time.monotonic() >= next_print:
                for key in sorted(fresh):
                    summary = stats[key].summary()
                    if summary is not None:
                        print(format_line(key, summary), flush=True)
                fresh.clear()
                next_print = time.monotonic() + args.interval
            if args.count and seen >= args.count:
                break
    summaries = {k: s for k, st in sorted(stats.items()) if (s := st.summary()) is not None}
    for key, summary in summaries.items():
        if args.json:
            print(json.dumps({"key": key, "clock": args.clock, **summary.as_dict()}), flush=True)
        else:
            print(f"total {format_line(key, summary)}", flush=True)
    if unstamped:
        print(f"fixstream hz: {unstamped} messages without a readable header.stamp_ns skipped", file=sys.stderr)
    if not summaries:
        why = "; ".join(f"{k}: {st.why_none}" for k, st in sorted(stats.items())[:5])
        print(f"fixstream hz: no key on {args.key_expr} had a rate" + (f" ({why})" if why else ""), file=sys.stderr)
        return exit_codes.TIMEOUT
    return exit_codes.OK
