"""Near-collinear geometry family of the LBL estimator (issue 16): wrong decisions, decision times, the decision
statistic against an independent exact ratio, and NEES on straight legs and in turns, for the honest and the
paper presets on the same simulated runs.

    python -m bench.bench_lbl_nearcollinear                 # every scenario lbl_nav_nc_*, BENCH_LBL_NC_RUNS each
    BENCH_LBL_NC_RUNS=1000 BENCH_LBL_NC_WORKERS=2 BENCH_LBL_NC_ONLY=lbl_nav_nc_3 python -m bench.bench_lbl_nearcollinear

Geometry from the scenario files (``scenarios/lbl_nav_nc_*.yaml``, the simulator's parameters); run i of a
scenario uses the seed ``scenario seed * 1,000,000 + i`` (fresh seeds, no overlap with the S1-S4 sets). Per run
and preset: the decision (time after launch, right or wrong: the accepted hypothesis is the one nearest the truth
at launch), the log ratio the decision was taken on, the independent exact log ratio of ``bounds.exact_log_ratio_at``
(linearised at the truth and its mirror, heading terms at the true dK and at the dK the mirror needs) on the same
data (paper: the buffered epochs the EKF had processed; honest: all of them), and the position NEES of every
valid fix, split by the truth's turn rate (turn: above 0.5 deg/s). Output: a JSON file and Markdown tables.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from multiprocessing import Pool
from pathlib import Path
from typing import Any

import numpy as np

from schemas.lbl_nav import LblEvent, LblFix
from services.lbl_nav.bounds import NoiseModel, exact_log_ratio_at
from services.lbl_nav.config import LblNavConfig
from services.lbl_nav.core import LblNavCore
from services.lbl_nav.metrics import binomial_upper95 as upper95
from services.lbl_nav.offline import feed
from services.lbl_nav.simulation import SimRun, simulate
from services.lbl_nav.simulator import sim_params
from services.player.scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent
NS = 1_000_000_000
LN10 = math.log(10.0)
TURN_DPS = 0.5


def one_run(args: tuple[str, int, str]) -> dict[str, Any]:
    path, seed, preset = args
    sc = load_scenario(path)
    spec = sim_params(sc).spec()
    sim = simulate(spec, np.random.default_rng(seed), seed)
    cfg = LblNavConfig(preset=preset, N_max=360, validate_outputs=False)  # type: ignore[arg-type]
    t0 = time.process_time()
    outs, _ = feed(LblNavCore(cfg), sim.messages)
    cpu = time.process_time() - t0
    return evaluate(sim, outs, cfg, preset, seed, cpu)


def evaluate(sim: SimRun, outs: list[Any], cfg: LblNavConfig, preset: str, seed: int, cpu: float) -> dict[str, Any]:
    i0, t0_ns = sim.i0, int(sim.stamps_ns[sim.i0])
    fixes = [o for o in outs if isinstance(o, LblFix) and o.launch_stamp_ns is not None]
    events = [o for o in outs if isinstance(o, LblEvent)]
    out: dict[str, Any] = {"seed": seed, "preset": preset, "cpu_s": cpu, "decided": False, "wrong": False}
    launch = next((f for f in fixes if len(f.hypotheses) == 2), None)
    dec = next((e for e in events if e.kind == "decision"), None)
    out["merged"] = any(e.kind == "merge" for e in events)
    if launch is None or dec is None:
        return out
    truth0 = (sim.x_m[i0], sim.y_m[i0])
    true_id = min(launch.hypotheses, key=lambda h: math.dist(h.estimate.mean[:2], truth0)).hypothesis_id
    k = sim.index_of(dec.header.stamp_ns)
    t_dec = (dec.header.stamp_ns - t0_ns) / NS
    sign = 1.0 if true_id == 1 else -1.0  # ratios as true over mirror
    noise = NoiseModel.of(sim.spec)
    i = k - i0
    if preset == "paper":
        n_buf = min(cfg.dN0 + i * cfg.dN, i0)
        exact = exact_log_ratio_at(sim, noise, k, n_buf)
    else:
        exact = exact_log_ratio_at(sim, noise, k)
    out.update(
        decided=True,
        wrong=dec.hypothesis_id != true_id,
        t_s=t_dec,
        log10_ratio=sign * float(dec.log10_ratio or 0.0),
        exact_log10=exact / LN10,
        detail=dec.detail,
    )
    # NEES of the valid fixes, straight vs turn (truth's heading rate)
    rate = np.degrees(np.abs(np.diff(sim.heading_true_rad, prepend=sim.heading_true_rad[0]))) / sim.spec.dt_s
    nees_s, nees_t = [], []
    for f in fixes:
        if not f.valid or f.estimate is None:
            continue
        j = sim.index_of(f.header.stamp_ns)
        e = np.array(f.estimate.mean[:2]) - (sim.x_m[j], sim.y_m[j])
        P = np.array(f.estimate.covariance)[:2, :2]
        v = float(e @ np.linalg.solve(P, e))
        (nees_t if rate[j] > TURN_DPS else nees_s).append(v)
    out["nees_straight"] = [float(np.mean(nees_s)), len(nees_s)] if nees_s else None
    out["nees_turn"] = [float(np.mean(nees_t)), len(nees_t)] if nees_t else None
    return out


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    n = len(rows)
    dec = [r for r in rows if r["decided"]]
    wrong = sum(r["wrong"] for r in rows)
    times = [r["t_s"] for r in dec]
    diffs = [r["log10_ratio"] - r["exact_log10"] for r in dec if not r["wrong"]]
    # consistency of the fixes that follow a correct decision (after a wrong one the filter tracks the mirror)
    ns = [r["nees_straight"] for r in dec if r.get("nees_straight") and not r["wrong"]]
    nt = [r["nees_turn"] for r in dec if r.get("nees_turn") and not r["wrong"]]
    return {
        "runs": n,
        "decided": len(dec),
        "wrong": wrong,
        "wrong_upper95": upper95(wrong, n),
        "merged": sum(r["merged"] for r in rows),
        "median_t_s": float(np.median(times)) if times else None,
        "p90_t_s": float(np.percentile(times, 90)) if times else None,
        "ratio_minus_exact_log10": (
            {"mean": float(np.mean(diffs)), "min": float(np.min(diffs)), "max": float(np.max(diffs))} if diffs else None
        ),
        "exact_at_decision_log10": [r["exact_log10"] for r in dec],
        "ratio_at_decision_log10": [r["log10_ratio"] for r in dec],
        "wrong_seeds": [r["seed"] for r in rows if r["wrong"]],
        "nees_straight": _nees(ns),
        "nees_turn": _nees(nt),
        "cpu_s_per_run": float(np.mean([r["cpu_s"] for r in rows])),
        "decisions": [{k: r[k] for k in ("seed", "wrong", "t_s", "log10_ratio", "exact_log10")} for r in dec],
    }


def _nees(per_run: list[list[float]]) -> dict[str, float] | None:
    """Mean position NEES (2 dof) over runs (each run's mean over its epochs) with the standard error over runs."""
    if not per_run:
        return None
    m = np.array([v for v, _ in per_run])
    return {
        "mean": float(m.mean()),
        "se": float(m.std(ddof=1) / math.sqrt(m.size)) if m.size > 1 else math.nan,
        "runs": int(m.size),
        "epochs": int(sum(c for _, c in per_run)),
    }


def main() -> int:
    runs = int(os.environ.get("BENCH_LBL_NC_RUNS", "200"))
    workers = int(os.environ.get("BENCH_LBL_NC_WORKERS", str(os.cpu_count() or 1)))
    only = os.environ.get("BENCH_LBL_NC_ONLY")
    presets = os.environ.get("BENCH_LBL_NC_PRESETS", "honest,paper").split(",")
    out_path = Path(os.environ.get("BENCH_LBL_NC_OUT", "bench_lbl_nearcollinear.json"))
    files = sorted((ROOT / "scenarios").glob("lbl_nav_nc_*.yaml"))
    if only:
        files = [f for f in files if f.stem in only.split(",")]
    result: dict[str, Any] = {"runs": runs, "scenarios": {}}
    with Pool(workers) as pool:
        for f in files:
            seed0 = load_scenario(f).seed * 1_000_000
            result["scenarios"][f.stem] = {}
            for preset in presets:
                t0 = time.time()
                rows = pool.map(one_run, [(str(f), seed0 + i, preset) for i in range(runs)], chunksize=4)
                s = summarise(rows)
                s["wall_s"] = time.time() - t0
                result["scenarios"][f.stem][preset] = s
                print(
                    f"{f.stem:22s} {preset:6s} runs {s['runs']:5d} decided {s['decided']:4d} wrong {s['wrong']:2d} "
                    f"(95% upper {100 * s['wrong_upper95']:.2f} %) median t {s['median_t_s']} p90 {s['p90_t_s']} "
                    f"ratio-exact {s['ratio_minus_exact_log10']} NEES {s['nees_straight']} / {s['nees_turn']} "
                    f"cpu/run {s['cpu_s_per_run']:.2f} s, {s['wall_s']:.0f} s",
                    flush=True,
                )
                out_path.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
