"""``fixstream play FILE``: play a scenario (YAML, or a scenario name in --dir) or replay an MCAP onto Zenoh.

A scenario waits until every service in its ``wait_for`` list holds a liveliness token (unless ``--no-wait``; for
at most ``--wait-timeout`` seconds, else the file's ``wait_timeout_s``), then publishes a start marker, the simulated
truth and sensor streams in stamp order at ``--rate`` times real time (0: as fast as possible) and an end marker
with the count per key.

An MCAP file is replayed in log-time order at ``--rate``, byte-identical to what was recorded. By default only the
keys a player publishes go back on Zenoh (fixstream/sensor/**, fixstream/truth/**, fixstream/scenario/**,
fixstream/group/*/uplink/**): replayed into a running stack, the services compute their fixes, tracks and
diagnostics again, and the recorded ones would sit beside them on the same keys. ``--all`` replays every key,
``--keys`` replays only the key expressions it names, ``--exclude`` leaves key expressions out (after either).
Channels that are not fixstream streams (the recorder's Foxglove scene and map channels) are left out quietly.

A progress line (messages, data time) is drawn on stderr when stderr is a terminal, or with ``--progress``.

Exit status: 0 done; 1 interrupted (Ctrl-C, SIGTERM) before the end; 2 a bad file, scenario, option or an
unreachable router; 3 the services to wait for did not come up within the wait timeout.
"""

from __future__ import annotations

import argparse
from typing import Any

from services.player.replay import MAX_REPLAY_GAP_S

from . import progress
from .common import add_zenoh_arguments, key_chunk, key_expr, non_negative_int, positive_seconds, rate, seconds, seed

#: ``--wait-timeout`` of a replay when not given (a scenario uses its file's ``wait_timeout_s``)
REPLAY_WAIT_TIMEOUT_S = 30.0


def _skipped(skipped: dict[str, int]) -> str:
    """``54 skipped: 54 not_kept (payloads over the recorder's max_payload_bytes, kept as their size only)``."""
    total = sum(skipped.values())
    if not total:
        return "0 skipped"
    why = {"not_kept": " (payloads over the recorder's max_payload_bytes: only their size was kept)"}
    reasons = ", ".join(f"{n} {reason}{why.get(reason, '')}" for reason, n in sorted(skipped.items()))
    return f"{total} skipped: {reasons}"


def _wait_for(text: str) -> str:
    """argparse ``type=``: ``service`` or ``service/instance``, as a scenario's ``wait_for`` (a usage error else)."""
    from services.player.scenario import wait_name

    try:
        return wait_name(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="scenario .yaml/.yml, a scenario name in --dir, or a recording .mcap")
    parser.add_argument("--rate", type=rate, default=1.0, help="times real time; 0 = as fast as possible")
    parser.add_argument(
        "--instance", type=key_chunk, help="player instance (header.source player/<instance>; default 'default')"
    )
    parser.add_argument("--seed", type=seed, help="override the scenario's seed")
    parser.add_argument(
        "--run", type=non_negative_int, help="play Monte-Carlo run I of --seed (as fixstream mc computes it)"
    )
    parser.add_argument("--no-wait", action="store_true", help="do not wait for the scenario's wait_for services")
    parser.add_argument(
        "--wait-for",
        action="append",
        type=_wait_for,
        default=[],
        metavar="SERVICE[/INSTANCE]",
        help="also wait for this service's liveliness before publishing (repeatable; works for .mcap too)",
    )
    parser.add_argument(
        "--wait-timeout",
        type=seconds,
        metavar="S",
        help="seconds to wait for the services; default: the scenario file's wait_timeout_s, for a recording"
        f" {REPLAY_WAIT_TIMEOUT_S:g}",
    )
    parser.add_argument("--dir", help="scenario directory for names (default $FIXSTREAM_SCENARIOS_DIR or scenarios)")
    parser.add_argument("--linger", type=seconds, default=0.5, help="seconds to stay connected after the end marker")
    progress.add_arguments(parser)
    rec = parser.add_argument_group("replay of a recording (.mcap)")
    rec.add_argument(
        "--max-gap",
        type=positive_seconds,
        default=MAX_REPLAY_GAP_S,
        metavar="S",
        help="a longer gap between two records' log times is paced as S seconds of data time, and counted",
    )
    which = rec.add_mutually_exclusive_group()
    which.add_argument(
        "--keys",
        action="append",
        type=key_expr,
        default=[],
        metavar="KEYEXPR",
        help="replay only the keys this expression matches (repeatable), instead of the player's keys",
    )
    which.add_argument(
        "--all", action="store_true", help="replay every key, the recorded fixes, tracks and diagnostics too"
    )
    rec.add_argument(
        "--exclude",
        action="append",
        type=key_expr,
        default=[],
        metavar="KEYEXPR",
        help="leave out the keys this expression matches (repeatable)",
    )
    add_zenoh_arguments(parser)


def _stop_on_signals() -> Any:
    import signal
    import threading

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    return stop


def _replay(args: argparse.Namespace) -> int:
    import sys
    import time
    from pathlib import Path

    from services.player.player import WaitTimeout, wait_for_alive
    from services.player.replay import replay
    from services.player.scenario import wait_keys
    from services.player.selection import KeySelection, selected_total
    from shared.mcap_io import McapReadError
    from shared.recovery import Recovery
    from shared.session import open_session

    from . import exit_codes
    from .common import zenoh_settings_from

    if not Path(args.file).is_file():
        print(f"fixstream play: {args.file}: no such file", file=sys.stderr)
        return exit_codes.USAGE
    select = KeySelection.from_options(args.keys, args.exclude, args.all)
    line = None
    if progress.wanted(args.progress):
        line = progress.ProgressLine(f"replay {Path(args.file).name}", total=selected_total(args.file, select))
    timeout = REPLAY_WAIT_TIMEOUT_S if args.wait_timeout is None else args.wait_timeout
    stop = _stop_on_signals()
    settings = zenoh_settings_from(args)
    session = open_session(settings)
    try:
        wait_for_alive(session, wait_keys(args.wait_for), timeout, stop)
        result = replay(
            session,
            args.file,
            rate=args.rate,
            stop=stop,
            select=select,
            progress=line.update if line else None,
            recovery=Recovery.of(settings),
            max_gap_s=args.max_gap,
        )
        if line is not None:
            line.finish()
        time.sleep(max(args.linger, 0.0))
    except WaitTimeout as exc:  # before OSError: a TimeoutError is one
        print(f"fixstream play: {args.file}: waiting for services: {exc}", file=sys.stderr)
        return exit_codes.TIMEOUT
    except McapReadError as exc:  # its message names the file
        print(f"fixstream play: {exc}", file=sys.stderr)
        return exit_codes.USAGE
    except OSError as exc:
        print(f"fixstream play: {args.file}: {exc}", file=sys.stderr)
        return exit_codes.USAGE
    finally:
        session.close()
    left = result.left_out
    notes = []
    if left.get("not_selected"):
        notes.append(f"{left['not_selected']} on keys not replayed ({select.describe()} replayed)")
    if left.get("foreign_channel"):
        notes.append(f"{left['foreign_channel']} on Foxglove/foreign channels")
    if result.tail_bytes:
        notes.append(f"the last {result.tail_bytes} bytes, an incomplete record (a file cut short or being written)")
    if result.gaps_shortened:
        notes.append(f"{result.gaps_shortened} gaps in the log times paced as {args.max_gap:g} s (--max-gap)")
    print(
        f"replayed {result.total} records on {len(result.published)} keys from {args.file} "
        f"({_skipped(result.skipped)}) in {result.wall_s:.2f} s" + (f"; left out: {', '.join(notes)}" if notes else ""),
        flush=True,
    )
    return exit_codes.OK if result.completed else exit_codes.FAILURE


def run(args: argparse.Namespace) -> int:
    import sys
    import time
    from pathlib import Path

    from . import exit_codes

    if args.rate < 0:
        print("fixstream play: --rate must be >= 0", file=sys.stderr)
        return exit_codes.USAGE
    if args.wait_timeout is not None and args.wait_timeout <= 0:
        print("fixstream play: --wait-timeout must be > 0", file=sys.stderr)
        return exit_codes.USAGE
    if Path(args.file).suffix == ".mcap":
        options = (("--seed", args.seed), ("--run", args.run), ("--instance", args.instance))
        given = [o for o, v in options if v is not None]
        if given:  # a recording replays its messages as recorded, headers included: these would be silently ignored
            print(f"fixstream play: {', '.join(given)} apply to a scenario file, not a recording", file=sys.stderr)
            return exit_codes.USAGE
        return _replay(args)
    if args.keys or args.exclude or args.all:
        print("fixstream play: --keys, --exclude and --all select keys of a recording (.mcap)", file=sys.stderr)
        return exit_codes.USAGE

    from services.player.player import WaitTimeout, play_scenario
    from services.player.scenario import ScenarioError, load_scenario, resolve
    from services.player.timeline import SimulationError
    from shared.recovery import Recovery
    from shared.session import open_session

    from .common import zenoh_settings_from

    try:
        scenario = load_scenario(resolve(args.file, args.dir))
        update: dict[str, Any] = {}
        if args.wait_for:
            update["wait_for"] = [*scenario.wait_for, *args.wait_for]
        if args.wait_timeout is not None:
            update["wait_timeout_s"] = args.wait_timeout  # the command line wins over the file
        scenario = scenario.model_copy(update=update) if update else scenario
    except ScenarioError as exc:
        print(f"fixstream play: {exc}", file=sys.stderr)
        return exit_codes.USAGE
    line = None
    if progress.wanted(args.progress):
        line = progress.ProgressLine(f"play {scenario.name}", data_total_s=scenario.duration_s)
    stop = _stop_on_signals()
    settings = zenoh_settings_from(args)
    session = open_session(settings)
    try:
        played = play_scenario(
            session,
            scenario,
            seed=args.seed,
            run=args.run,
            instance=args.instance or "default",
            rate=args.rate,
            wait=not args.no_wait,
            stop=stop,
            progress=line.update if line else None,
            recovery=Recovery.of(settings),
        )
        if line is not None:
            line.finish()
        time.sleep(max(args.linger, 0.0))
    except WaitTimeout as exc:
        print(f"fixstream play: {scenario.name}: waiting for services: {exc}", file=sys.stderr)
        return exit_codes.TIMEOUT
    except SimulationError as exc:  # a platform flown twice, a run too big to hold: the file's fault, one line
        print(f"fixstream play: {scenario.name}: {exc}", file=sys.stderr)
        return exit_codes.USAGE
    finally:
        session.close()
    print(
        f"{scenario.name}: published {played.total} messages on {len(played.published)} keys in {played.wall_s:.2f} s",
        flush=True,
    )
    return exit_codes.OK if played.completed else exit_codes.FAILURE
