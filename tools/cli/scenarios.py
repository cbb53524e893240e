"""``fixstream scenarios [list | show NAME | validate [FILES...]]``: the scenario files and what they publish.

``list`` (default) prints every scenario in ``--dir`` with its duration, simulators and description;
``show`` prints one scenario with every default filled in and the streams it publishes (key, type, count,
rate); ``validate`` checks files (default: every file in ``--dir``) and exits 1 if any is invalid.
The file format is documented in docs/scenarios.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .common import seed


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", nargs="?", choices=["list", "show", "validate"], default="list")
    parser.add_argument("targets", nargs="*", help="show: one scenario name or file; validate: files")
    parser.add_argument("--dir", help="scenario directory (default $FIXSTREAM_SCENARIOS_DIR or scenarios)")
    parser.add_argument("--seed", type=seed, help="show: seed for the stream summary (default: the scenario's)")


def _list(directory: Any) -> int:
    from services.player.scenario import ScenarioError, load_scenario, scenario_files

    files = scenario_files(directory)
    if not files:
        print(f"no scenario files in {directory}/")
        return 0
    rows: list[tuple[str, ...]] = []
    for f in files:
        try:
            s = load_scenario(f)
        except ScenarioError as exc:
            rows.append((f.name, "INVALID", str(exc).splitlines()[0]))
            continue
        kinds = ",".join(sorted({sim.kind for sim in s.simulators}))
        desc = " ".join(s.description.split())
        rows.append((f.name, s.name, f"{s.duration_s:9.1f} s", kinds, desc[:70]))
    widths = [max((len(r[i]) for r in rows if len(r) > i + 1), default=0) for i in range(4)]  # last: not padded
    for row in rows:
        print(" ".join(cell.ljust(widths[i]) if i < len(row) - 1 else cell for i, cell in enumerate(row)).rstrip())
    return 0


def _show(target: str, directory: Any, seed: int | None) -> int:
    from collections import Counter

    import yaml

    from services.player.scenario import load_scenario, resolve
    from services.player.timeline import scenario_events

    path = resolve(target, directory)
    s = load_scenario(path)
    doc = s.model_dump(mode="json")
    for i, sim in enumerate(doc["simulators"]):
        sim["params"] = s.simulator_params(i).model_dump(mode="json")
    print(f"# {path}")
    print(yaml.safe_dump(doc, sort_keys=False, width=120), end="")
    events = scenario_events(s, seed)
    counts = Counter(e.key for e in events)
    types = {e.key: type(e.msg).__name__ for e in events}
    print(f"# streams (seed {s.seed if seed is None else seed}): key, type, messages, mean rate")
    for key in sorted(counts):
        print(f"#   {key:50s} {types[key]:12s} {counts[key]:8d} {counts[key] / s.duration_s:8.2f} Hz")
    print(f"#   {'fixstream/scenario/' + s.name:50s} {'ScenarioMarker':12s} {2:8d}  start + end")
    return 0


def _validate(targets: list[str], directory: Any) -> int:
    from services.player.scenario import ScenarioError, load_scenario, scenario_files
    from services.player.timeline import SimulationError, build

    files = targets or [str(f) for f in scenario_files(directory)]
    if not files:
        print(f"no scenario files in {directory}/")
        return 1
    bad = 0
    for f in files:
        try:
            s = load_scenario(f)
        except ScenarioError as exc:
            bad += 1
            print(exc)
            continue
        try:  # what only building the simulators checks: one platform flown twice, a run too big to hold
            build(s, s.seed)
        except SimulationError as exc:
            bad += 1
            print(f"{f}: {exc}")
            continue
        print(f"{f}: OK ({s.name}, {s.duration_s:g} s, {len(s.simulators)} simulator(s))")
    return 1 if bad else 0


def run(args: argparse.Namespace) -> int:
    import sys

    from services.player.scenario import ScenarioError, default_dir
    from services.player.timeline import SimulationError

    directory = args.dir or default_dir()
    if args.dir is not None and not Path(args.dir).is_dir():
        print(f"fixstream scenarios: --dir {args.dir}: not a directory", file=sys.stderr)
        return 2
    if args.action == "list" and args.targets:
        print("fixstream scenarios list: takes no names (show NAME, validate FILE ...)", file=sys.stderr)
        return 2
    try:
        if args.action == "list":
            return _list(directory)
        if args.action == "show":
            if len(args.targets) != 1:
                print("fixstream scenarios show: give exactly one scenario name or file", file=sys.stderr)
                return 2
            return _show(args.targets[0], directory, args.seed)
        return _validate(args.targets, directory)
    except ScenarioError as exc:
        print(exc, file=sys.stderr)
        return 2
    except SimulationError as exc:
        print(f"fixstream scenarios: {exc}", file=sys.stderr)
        return 2
