"""``fixstream mc SCENARIO --runs N --seed S --out FILE``: Monte-Carlo runs of a scenario, in-process.

Each run simulates the scenario with the seed sequence ``SeedSequence(S).spawn(N)[i]``, feeds the ordered
events to the scenario's estimator cores (``services/<kind>/mc.py``) and computes the built-in
``sensor_stats``. Runs are spread over ``--workers`` processes (default: every core), or over the workers of a
Dask distributed cluster with ``--scheduler tcp://HOST:PORT`` (needs ``pip install 'fixstream[dask]'``), with a
progress bar on stderr when stderr is a terminal (``--progress``: always); the JSON (per-run and aggregate metrics)
is identical for any number of workers and either way. ``--out`` is checked before the runs start. Exit status: 0
done, 2 bad arguments, scenario or ``--out``, no dask.distributed or no scheduler reachable.
"""

from __future__ import annotations

import argparse

from . import progress
from .common import positive_int, seed


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", help="scenario .yaml or a scenario name in --dir")
    parser.add_argument("--runs", type=positive_int, required=True, help="number of Monte-Carlo runs")
    parser.add_argument("--seed", type=seed, help="root seed (default: the scenario's seed)")
    parser.add_argument("--out", required=True, help="metrics JSON file to write")
    parser.add_argument("--workers", type=int, help="processes (default: os.cpu_count())")
    parser.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="run on the Dask distributed cluster of this scheduler (optional extra fixstream[dask])",
    )
    parser.add_argument("--dir", help="scenario directory for names (default $FIXSTREAM_SCENARIOS_DIR or scenarios)")
    progress.add_arguments(parser, "the progress bar")


def run(args: argparse.Namespace) -> int:
    import sys
    from pathlib import Path

    from services.player.scenario import ScenarioError, load_scenario, resolve
    from services.player.timeline import SimulationError
    from tools import montecarlo

    from .common import check_output_file

    if args.runs < 1 or (args.workers is not None and args.workers < 1):
        print("fixstream mc: --runs and --workers must be >= 1", file=sys.stderr)
        return 2
    if args.scheduler is not None and args.workers is not None:
        print(
            "fixstream mc: --workers is for local processes; with --scheduler the cluster's workers run",
            file=sys.stderr,
        )
        return 2
    if args.scheduler is not None and not montecarlo.dask_available():
        print(f"fixstream mc: {montecarlo.NO_DASK}", file=sys.stderr)
        return 2
    check_output_file(Path(args.out))  # before the runs, not after them
    try:
        scenario = load_scenario(resolve(args.scenario, args.dir))
        if args.scheduler is not None:
            print(
                f"fixstream mc: {args.runs} runs on the Dask cluster at {args.scheduler}", file=sys.stderr, flush=True
            )
        result = montecarlo.run_montecarlo(
            scenario,
            args.runs,
            seed=args.seed,
            workers=args.workers,
            progress=progress.wanted(args.progress),
            scheduler=args.scheduler,
        )
    except (ScenarioError, montecarlo.MonteCarloError, SimulationError) as exc:
        print(f"fixstream mc: {exc}", file=sys.stderr)
        return 2
    montecarlo.write(result, args.out)
    print(f"{scenario.name}: {args.runs} runs, seed {result['seed']}, metrics in {args.out}", flush=True)
    return 0
