"""Write the reference-map files that scenario files name: ``python -m services.terrain_nav.mapfiles FILE.yaml ...``.

For every ``terrain_nav`` simulator on synthetic terrain with a ``map_file`` (and so a fixed
``terrain_seed``), the generated DEM of its terrain is saved as ``<map_file>.npy`` with its JSON sidecar. The
estimator service loads that file; the simulator checks it against the terrain it flies over. A simulator
flying a ``terrain_file`` is skipped: its ``map_file`` is another DEM and is never overwritten.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .maps import resolve_map_path, save_npy
from .simulator import KIND, TerrainFlightParams, generated_world


def write_maps(scenario_paths: list[Path]) -> list[Path]:
    """Write the ``map_file`` of every terrain_nav simulator in these scenario files; returns the .npy files."""
    from services.player.scenario import load_scenario

    written: list[Path] = []
    for path in scenario_paths:
        scenario = load_scenario(path)
        for i, spec in enumerate(scenario.simulators):
            params = scenario.simulator_params(i)
            if spec.kind != KIND or not isinstance(params, TerrainFlightParams):
                continue
            if params.map_file is None or params.terrain_seed is None or params.terrain_file is not None:
                continue  # a terrain_file scenario's map_file is another DEM: never overwritten
            target = resolve_map_path(params.map_file).with_suffix(".npy")
            target.parent.mkdir(parents=True, exist_ok=True)
            written.append(save_npy(generated_world(params, params.terrain_seed).ref_map, target))
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m services.terrain_nav.mapfiles",
        description="Write the reference-map files named by the terrain_nav simulators of scenario files.",
    )
    parser.add_argument("scenarios", nargs="+", type=Path, help="scenario YAML files")
    args = parser.parse_args(argv)
    for p in write_maps(args.scenarios):
        print(f"wrote {p} and {p.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
