"""Attitude estimator (issue 15): does a fixed-lag smoothed estimate meet the manoeuvre targets?

The default preset's IMM with ``smoother_lag_scans`` L = 1, 2, 3 (``services/attitude/smoother.py``: every model's
state augmented with its last L states) on the four family files and the paper's flight, scored exactly like
``bench_attitude_manoeuvre`` (``mc.run_metrics`` and ``metrics.phase_table``: turn / manoeuvre / straight / steady
phases from the truth's ``extra``, from scan 20, the 9-state ANEES against its chi2(9N) 95 % band), against the
real-time IMM (L = 0) and preset paper on the same plots (``fixstream mc``'s run seeds from 1). Each L is its own
core; the bench checks that the real-time estimates of every L are those of L = 0 (the smoother must not change
them) and times each core per plot.

    ATTITUDE_SMOOTHER_RUNS=10 ATTITUDE_SMOOTHER_WORKERS=2 python -m bench attitude_smoother
    ATTITUDE_SMOOTHER_LAGS=1,2,3,5 ...                     # the lags (default 1, 2, 3)
    ATTITUDE_SMOOTHER_FILES=attitude_9s15 ...              # only these files (default: the family and 9s15)

The smoothed stream has no estimate for the last L plots of a flight (they are never L plots old): its "psi
defined" share is lower by about L / 81 on the phases that run to the end of the flight. The time per plot is
the best of three single-process runs of one core over one run of ``attitude_turns_light`` (6 flights, 600
plots; every output built and schema-validated), so that the machine's other load counts as little as possible.
"""

from __future__ import annotations

import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from services.attitude.flights import FILES
from services.attitude.mc import aggregate, core_outputs, run_metrics
from services.attitude.metrics import phase_table
from services.player.scenario import load_scenario
from services.player.timeline import build, player_source, stamp
from tools.montecarlo import EVENT_INSTANCE

from .bench_attitude_manoeuvre import PHASES, SCENARIOS, SEED
from .report import emit, table

LAGS = tuple(int(v) for v in os.environ.get("ATTITUDE_SMOOTHER_LAGS", "1,2,3").split(","))
#: the streams scored: preset paper, the real-time IMM (L = 0) and the smoothed estimate of each lag
STREAMS = ("paper", "L=0", *(f"L={lag}" for lag in LAGS))
COST_FILE = "attitude_turns_light"


def _params(config: dict[str, Any]) -> dict[str, Any]:
    return {"reference": False, "config": config}


def run_one(name: str, run: int) -> dict[str, Any]:
    """One run of one file: per stream the run_metrics record (with the empty counters aggregate wants), and per
    core the seconds and the plots it took."""
    sc = load_scenario(SCENARIOS / f"{name}.yaml")
    events = list(stamp(build(sc, SEED, run).raw_events(), player_source(EVENT_INSTANCE)))
    out: dict[str, Any] = {"metrics": {}, "seconds": {}, "plots": 0}
    base: list[Any] | None = None
    for label, config in [
        ("paper", {"preset": "paper"}),
        *[(f"L={lag}", {"smoother_lag_scans": lag}) for lag in (0, *LAGS)],
    ]:
        params = _params(config)
        t0 = time.perf_counter()
        outputs, rejected, core = core_outputs(events, params, sc)
        out["seconds"][label] = time.perf_counter() - t0
        realtime = [e for e in outputs if "SMOOTHED" not in e.msg.flags]
        if label == "L=0":
            base = realtime
            out["plots"] = len(realtime)
        elif label != "paper" and realtime != base:
            raise AssertionError(f"{name} run {run} {label}: the smoother changed a real-time estimate")
        if label in ("paper", "L=0"):
            out["metrics"][label] = {**run_metrics(outputs, events, params, sc), "rejected": rejected, "core": core}
        else:
            smoothed = run_metrics(outputs, events, params, sc, smoothed=True)
            out["metrics"][label] = {**smoothed, "rejected": rejected, "core": core}
    return out


def cost_per_plot(repeats: int = 3) -> dict[str, float]:
    """us per plot of one core (preset paper, then the default preset with each lag) over run 0 of COST_FILE:
    the best of ``repeats`` runs in this process."""
    sc = load_scenario(SCENARIOS / f"{COST_FILE}.yaml")
    events = list(stamp(build(sc, SEED, 0).raw_events(), player_source(EVENT_INSTANCE)))
    out: dict[str, float] = {}
    for label, config in [
        ("paper", {"preset": "paper"}),
        *[(f"L={lag}", {"smoother_lag_scans": lag}) for lag in (0, *LAGS)],
    ]:
        best = math.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            outputs, _, _ = core_outputs(events, _params(config), sc)
            best = min(best, time.perf_counter() - t0)
        out[label] = 1e6 * best / sum(1 for e in outputs if "SMOOTHED" not in e.msg.flags)
    return out


def _row(label: str, stream: str, phase: str, r: dict[str, Any]) -> list[Any]:
    rms, nees = r["rms_deg"], r["nees"]
    band = nees["band_at_min_runs"]
    return [
        label,
        stream,
        phase,
        r["samples"],
        rms["psi"],
        rms["theta"],
        rms["gamma"],
        r["defined"]["psi"],
        nees["anees_mean"],
        f"[{band[0]:.1f}, {band[1]:.1f}]" if band else "-",
        nees["anees_in_band"],
        nees["sample_in_95"],
    ]


def _ratio(phases: dict[str, Any]) -> float | None:
    turn, straight = phases.get("turn"), phases.get("straight")
    if not turn or not straight or not turn["rms_deg"]["psi"] or not straight["rms_deg"]["psi"]:
        return None
    return float(turn["rms_deg"]["psi"] / straight["rms_deg"]["psi"])


def main() -> None:
    runs = int(os.environ.get("ATTITUDE_SMOOTHER_RUNS", "10"))
    workers = int(os.environ.get("ATTITUDE_SMOOTHER_WORKERS", "1"))
    chosen = os.environ.get("ATTITUDE_SMOOTHER_FILES")
    files = chosen.split(",") if chosen else [*FILES, "attitude_9s15"]
    family = [n for n in FILES if n in files]
    tasks = [(name, run) for name in files for run in range(runs)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=workers) as pool:
        results = list(pool.map(run_one, *zip(*tasks, strict=True)))
    per_file: dict[str, dict[str, list[dict[str, Any]]]] = {n: {s: [] for s in STREAMS} for n in files}
    seconds = dict.fromkeys(STREAMS, 0.0)
    plots = 0
    for (name, _), res in zip(tasks, results, strict=True):
        for s in STREAMS:
            per_file[name][s].append(res["metrics"][s])
            seconds[s] += res["seconds"][s]
        plots += res["plots"]
    figures: dict[str, Any] = {"runs_per_file": runs, "seed": SEED, "seconds": time.perf_counter() - t0}
    rows: list[list[Any]] = []
    ratio_rows: list[list[Any]] = []
    groups = [("family", family)] if family else []
    for label, names in [*groups, *[(n.removeprefix("attitude_"), [n]) for n in files]]:
        for s in STREAMS:
            aggs = [aggregate(per_file[n][s]) for n in names]
            phases = phase_table([p for a in aggs for p in a["phase_samples"]])
            figures[f"{label}/{s}"] = phases
            rows += [_row(label, s, ph, phases[ph]) for ph in PHASES if ph in phases]
            ratio_rows.append([label, s, _ratio(phases)])
    cost = cost_per_plot()
    figures["us_per_plot"] = cost
    figures["pool_seconds"] = seconds
    figures["pool_plots"] = plots
    headers = [
        "scenario",
        "stream",
        "phase",
        "samples",
        "psi",
        "theta",
        "gamma",
        "psi defined",
        "ANEES",
        "band",
        "ANEES in band",
        "NEES in 95%",
    ]
    emit("attitude_smoother", headers, rows, figures)
    print("\n## heading RMS turn / straight\n")
    print(table(["scenario", "stream", "turn / straight"], ratio_rows))
    print(f"\n## core time per plot (us, every output built and validated; best of 3 on {COST_FILE})\n")
    print(table(["stream", "us per plot"], [[s, c] for s, c in cost.items()]))


if __name__ == "__main__":
    main()
