"""Attitude estimator (digest 004, issue 15) on manoeuvring flights: the default preset against preset paper.

Every scenario file of the manoeuvring family (``scenarios/attitude_turns_light.yaml``,
``attitude_turns_transport.yaml``, ``attitude_climbs.yaml``, ``attitude_agile.yaml``: 24 flights) and the
paper's straight flight (``attitude_9s15.yaml``) is run through ``fixstream mc``'s code path
(:func:`tools.montecarlo.run_montecarlo`: the player's events, one core per run, the plugin's metrics) with
each preset, and the flight-phase statistics (:func:`services.attitude.metrics.phase_table`) are printed per
preset and phase, pooled over the family and per file: RMS error of heading, pitch, roll (earth frame) and of
the three LOS angles; the state NEES (mean ANEES, the share of scans whose ANEES lies in its chi2(9N) 95 % band,
the share of single NEES values inside the chi2(9) 95 % interval); the VALID consistency (share of estimates
VALID, mean (error / sigma)^2 of the heading among them, share within 2 sigma); resets and gated plots.

    ATTITUDE_BENCH_RUNS=100 python -m bench attitude_manoeuvre     # the runs per file (default 100)

Seeds: ``fixstream mc``'s run seeds from seed 1 (the same plots for both presets: common random numbers).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from services.attitude.flights import FILES
from services.attitude.metrics import phase_table
from services.player.scenario import load_scenario
from tools.montecarlo import run_montecarlo

from .report import emit

SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"
PRESETS = ("paper", "manoeuvre")
PHASES = ("turn", "manoeuvre", "straight", "steady")
SEED = 1


def run_file(name: str, preset: str, runs: int, workers: int) -> dict[str, Any]:
    """The aggregate of the attitude estimator of scenario ``name`` with ``preset`` (reference rules off)."""
    sc = load_scenario(SCENARIOS / f"{name}.yaml")
    est = sc.estimators[0]
    params = {
        **dict(est.params),
        "reference": False,
        "config": {**dict(est.params).get("config", {}), "preset": preset},
    }
    sc = sc.model_copy(update={"estimators": [est.model_copy(update={"params": params})]})
    result = run_montecarlo(sc, runs, seed=SEED, workers=workers, progress=False)
    agg: dict[str, Any] = result["aggregate"]["estimators"][est.instance]
    return agg


def rows_of(label: str, preset: str, phases: dict[str, Any], core: dict[str, int]) -> list[list[Any]]:
    rows = []
    for ph in PHASES:
        r = phases.get(ph)
        if r is None:
            continue
        rms, nees, valid = r["rms_deg"], r["nees"], r["valid"]["psi"]
        rows.append(
            [
                label,
                preset,
                ph,
                r["samples"],
                rms["psi"],
                rms["theta"],
                rms["gamma"],
                rms["psi_los"],
                rms["theta_los"],
                rms["gamma_los"],
                r["defined"]["psi"],
                nees["anees_mean"],
                nees["anees_in_band"],
                nees["sample_in_95"],
                valid["share"],
                valid["mean_z2"],
                valid["within_2sigma"],
                core.get("reset_nis", 0),
                core.get("innovation_gate", 0),
            ]
        )
    return rows


def main() -> None:
    runs = int(os.environ.get("ATTITUDE_BENCH_RUNS", "100"))
    workers = int(os.environ.get("ATTITUDE_BENCH_WORKERS", "1"))
    files = [*FILES, "attitude_9s15"]
    results: dict[str, dict[str, Any]] = {}
    t0 = time.perf_counter()
    for preset in PRESETS:
        for name in files:
            results[f"{name}/{preset}"] = run_file(name, preset, runs, workers)
    rows: list[list[Any]] = []
    figures: dict[str, Any] = {"runs_per_file": runs, "seed": SEED, "seconds": time.perf_counter() - t0}
    for preset in PRESETS:
        family = [results[f"{name}/{preset}"] for name in FILES]
        pooled = phase_table([s for agg in family for s in agg["phase_samples"]])
        core: dict[str, int] = {}
        for agg in family:
            for k, n in agg["core"].items():
                core[k] = core.get(k, 0) + int(n)
        rows += rows_of("family", preset, pooled, core)
        figures[f"family/{preset}"] = {"phases": pooled, "core": core}
    for name in files:
        for preset in PRESETS:
            agg = results[f"{name}/{preset}"]
            rows += rows_of(name.removeprefix("attitude_"), preset, agg["phases"], agg["core"])
            figures[f"{name}/{preset}"] = {"phases": agg["phases"], "core": agg["core"]}
    headers = [
        "scenario",
        "preset",
        "phase",
        "samples",
        "psi",
        "theta",
        "gamma",
        "psi_los",
        "theta_los",
        "gamma_los",
        "psi defined",
        "ANEES",
        "ANEES in band",
        "NEES in 95%",
        "VALID share",
        "VALID z2 psi",
        "VALID |z|<=2",
        "NIS resets",
        "gated",
    ]
    emit("attitude_manoeuvre", headers, rows, figures)


if __name__ == "__main__":
    main()
