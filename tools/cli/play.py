"""``fixstream play FILE``: play a scenario (YAML, or a scenario name in --dir) or replay an MCAP onto Zenoh.

A scenario waits until every service in its ``wait_for`` list holds a liveliness token (unless
``--no-wait``), then publishes a start marker, the simulated truth and sensor streams in stamp order at
``--rate`` times real time (0: as fast as possible) and an end marker with the count per key.
An MCAP file is replayed in log-time order at ``--rate``, byte-identical to what was recorded.
Exit status: 0 done, 1 interrupted, 2 bad file, 3 the services to wait for did not come up.
"""

from __future__ import annotations

import argparse

from .common import add_zenoh_arguments


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="scenario .yaml/.yml, a scenario name in --dir, or a recording .mcap")
    parser.add_argument("--rate", type=float, default=1.0, help="times real time; 0 = as fast as possible")
    parser.add_argument("--instance", default="default", help="player instance (header.source player/<instance>)")
    parser.add_argument("--seed", type=int, help="override the scenario's seed")
    parser.add_argument("--run", type=int, help="play Monte-Carlo run I of --seed (as fixstream mc computes it)")
    parser.add_argument("--no-wait", action="store_true", help="do not wait for the scenario's wait_for services")
    parser.add_argument(
        "--wait-for",
        action="append",
        default=[],
        metavar="SERVICE[/INSTANCE]",
        help="also wait for this service's liveliness before publishing (repeatable; works for .mcap too)",
    )
    parser.add_argument("--wait-timeout", type=float, default=30.0, help="seconds to wait for --wait-for services")
    parser.add_argument("--dir", help="scenario directory for names (default $FIXSTREAM_SCENARIOS_DIR or scenarios)")
    parser.add_argument("--linger", type=float, default=0.5, help="seconds to stay connected after the end marker")
    add_zenoh_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import signal
    import sys
    import threading
    import time
    from pathlib import Path

    from shared.session import open_session

    from .common import zenoh_settings_from

    if args.rate < 0:
        print("fixstream play: --rate must be >= 0", file=sys.stderr)
        return 2
    stop = threading.Event()

    def install_signal_handlers() -> None:
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
        signal.signal(signal.SIGINT, lambda *_: stop.set())

    if Path(args.file).suffix == ".mcap":
        from services.player.replay import replay
        from shared.mcap_io import McapReadError

        if not Path(args.file).is_file():
            print(f"fixstream play: {args.file}: no such file", file=sys.stderr)
            return 2
        from services.player.player import WaitTimeout, wait_for_alive
        from services.player.scenario import wait_keys

        install_signal_handlers()
        session = open_session(zenoh_settings_from(args))
        try:
            wait_for_alive(session, wait_keys(args.wait_for), args.wait_timeout, stop)
            result = replay(session, args.file, rate=args.rate, stop=stop)
            time.sleep(max(args.linger, 0.0))
        except (McapReadError, OSError) as exc:
            print(f"fixstream play: {args.file}: {exc}", file=sys.stderr)
            return 2
        except WaitTimeout as exc:
            print(f"fixstream play: {args.file}: waiting for services: {exc}", file=sys.stderr)
            return 3
        finally:
            session.close()
        print(
            f"replayed {result.total} records on {len(result.published)} keys from {args.file} "
            f"({sum(result.skipped.values())} skipped) in {result.wall_s:.2f} s",
            flush=True,
        )
        return 0 if result.completed else 1

    from services.player.player import WaitTimeout, play_scenario
    from services.player.scenario import ScenarioError, load_scenario, resolve

    try:
        scenario = load_scenario(resolve(args.file, args.dir))
        if args.wait_for:
            scenario = scenario.model_copy(update={"wait_for": [*scenario.wait_for, *args.wait_for]})
    except ScenarioError as exc:
        print(f"fixstream play: {exc}", file=sys.stderr)
        return 2
    install_signal_handlers()
    session = open_session(zenoh_settings_from(args))
    try:
        played = play_scenario(
            session,
            scenario,
            seed=args.seed,
            run=args.run,
            instance=args.instance,
            rate=args.rate,
            wait=not args.no_wait,
            stop=stop,
        )
        time.sleep(max(args.linger, 0.0))
    except WaitTimeout as exc:
        print(f"fixstream play: {scenario.name}: waiting for services: {exc}", file=sys.stderr)
        return 3
    finally:
        session.close()
    print(
        f"{scenario.name}: published {played.total} messages on {len(played.published)} keys in {played.wall_s:.2f} s",
        flush=True,
    )
    return 0 if played.completed else 1
