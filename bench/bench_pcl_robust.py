"""PCL tracker beyond the paper's case (issue 15): manoeuvres, dense clutter, crossing targets, paper accuracy.

Every figure comes from the repository's scenario files run as ``fixstream mc`` runs them (the player's
events of run r, ``services.pcl_tracker.mc.run_core`` per estimator entry, the same events for every entry):

* ``pcl_tracker_manoeuvre_{05g,1g,2g}.yaml``: runs in which the target keeps one track id for the whole run
  and is tracked at the end, with a 95 % Clopper-Pearson interval; NEES (6 dof) of the matched track and NIS
  (4 dof, the bistatic d² of its plot) in the turn (turn_start < t <= turn_end) and on the straight legs
  (the rest, after confirmation): the mean over all samples, and the fraction of scans whose mean over the
  runs lies in the two-sided 95 % band [chi2_{dR}(0.025), chi2_{dR}(0.975)] / R for R runs at that scan;
  position RMSE in the turn and on the straight legs;
* ``pcl_tracker_dense_clutter.yaml``: targets that ever get a confirmed track (of 100), targets tracked at
  the last scan, false confirmed tracks per run, CPU ms per scan;
* ``pcl_tracker_crossing.yaml``: ID switches (swaps / restarts), fragmentations, breaks, the former count
  (``assignment_changes``), GOSPA and its missed / false parts per scan;
* ``pcl_tracker_paper.yaml``: runs with exactly one track id and the final error, default vs paper;
* the paper scenario's accuracy (digest Table A times) with ``experiments.run_single_target``, 1,000 runs,
  ``default_rng(2024)``, no gating (the digest's §3.4 setup), for preset paper and the default.

``python -m bench pcl_robust`` (about 15-30 min on the shared 2-core machine); ``PCL_ROBUST_SCALE=0.1``
for a quick look. Results in ``bench/results/pcl_robust.json``.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import beta, chi2

from services.pcl_tracker import mc
from services.pcl_tracker.config import PclTrackerConfig
from services.pcl_tracker.experiments import rmse_over_runs, run_single_target
from services.pcl_tracker.simulation import noisy_plots, paper_truth
from services.player.scenario import Scenario, load_scenario
from services.player.timeline import scenario_events

from .report import emit

REPO = Path(__file__).resolve().parent.parent
SCALE = float(os.environ.get("PCL_ROBUST_SCALE", "1"))
N_MANOEUVRE = {"rx1-fm": 200, "rx1-fm-paper": 100, "rx1-fm-q10": 100}
N_DENSE = 10
N_CROSSING = 100
N_PAPER_STREAM = 200
N_PAPER_LOOP = 1000
TABLE_A_T = (3, 6, 9, 15, 30, 45, 51, 60, 90, 120, 150)
TABLE_A_POS = (182, 145, 128, 104, 83, 59, 45, 38, 44, 53, 63)
TABLE_A_VEL = (58.9, 29.4, 20.8, 10.7, 4.1, 2.4, 1.9, 1.6, 1.1, 1.0, 1.0)


def n_runs(n: int) -> int:
    return max(2, round(n * SCALE))


def clopper_pearson(k: int, n: int) -> tuple[float, float]:
    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    return lo, hi


def scenario(name: str) -> Scenario:
    return load_scenario(REPO / "scenarios" / f"pcl_tracker_{name}.yaml")


def run_all(sc: Scenario, runs: dict[str, int]) -> tuple[dict[str, list[dict[str, Any]]], dict[str, float]]:
    """Per estimator instance: its mc.run_core result for runs 0..n-1 (shared events), and CPU s per run."""
    out: dict[str, list[dict[str, Any]]] = {e.instance: [] for e in sc.estimators if e.instance in runs}
    cpu: dict[str, float] = dict.fromkeys(out, 0.0)
    for r in range(max(runs.values())):
        events = scenario_events(sc, run=r)
        for est in sc.estimators:
            if est.instance in runs and r < runs[est.instance]:
                t0 = time.process_time()
                out[est.instance].append(mc.run_core(events, dict(est.params), sc))
                cpu[est.instance] += time.process_time() - t0
    return out, {k: cpu[k] / max(len(v), 1) for k, v in out.items()}


def segment_consistency(per_run: list[dict[str, Any]], mask: np.ndarray, key: str, dof: int) -> dict[str, float]:
    """Mean of a per-scan statistic (NEES: key nees_sum / n_matched; NIS: nis_sum / n_nis) over the scans in
    ``mask``, and the fraction of those scans whose across-run mean lies in its 95 % chi-square band."""
    count_key = "n_matched" if key == "nees_sum" else "n_nis"
    S = np.array([r[key] for r in per_run], dtype=float)
    N = np.array([r[count_key] for r in per_run], dtype=float)
    total, n_total, inside, n_scans = 0.0, 0.0, 0, 0
    for k in np.flatnonzero(mask):
        R = N[:, k].sum()
        if R < 2:
            continue
        m = S[:, k].sum() / R
        lo, hi = chi2.ppf(0.025, dof * R) / R, chi2.ppf(0.975, dof * R) / R
        inside += int(lo <= m <= hi)
        n_scans += 1
        total += S[:, k].sum()
        n_total += R
    return {"mean": total / max(n_total, 1), "in_band": inside / max(n_scans, 1), "scans": n_scans}


def manoeuvres() -> tuple[list[tuple[Any, ...]], list[tuple[Any, ...]], dict[str, Any]]:
    hold_rows, cons_rows, figs = [], [], {}
    for tag, g in (("05g", 0.5), ("1g", 1.0), ("2g", 2.0)):
        sc = scenario(f"manoeuvre_{tag}")
        tp = sc.simulators[0].params["targets"][0]
        ts, te = float(tp["turn_start_s"]), float(tp["turn_end_s"])
        res, cpu = run_all(sc, {k: n_runs(v) for k, v in N_MANOEUVRE.items()})
        for inst, per_run in res.items():
            held = sum(
                len(r["track_ids_per_target"]["0"]) == 1 and r["final_matched"][0] and r["n_tracks_created"] >= 1
                for r in per_run
            )
            ids = float(np.mean([len(r["track_ids_per_target"]["0"]) for r in per_run]))
            n = len(per_run)
            lo, hi = clopper_pearson(held, n)
            t = np.array(per_run[0]["t_s"])
            turn = (t > ts) & (t <= te)
            straight = ~turn
            pos = np.array([r["pos_sq_err_m2"] for r in per_run])
            nm = np.array([r["n_matched"] for r in per_run])
            rms = {
                seg: math.sqrt(pos[:, m].sum() / max(nm[:, m].sum(), 1))
                for seg, m in (("turn", turn), ("straight", straight))
            }
            nees = {
                seg: segment_consistency(per_run, m, "nees_sum", 6)
                for seg, m in (("turn", turn), ("straight", straight))
            }
            nis = {
                seg: segment_consistency(per_run, m, "nis_sum", 4)
                for seg, m in (("turn", turn), ("straight", straight))
            }
            hold_rows.append(
                (f"{g:g} g", inst, f"{held}/{n}", f"[{lo:.3f}, {hi:.3f}]", round(ids, 2), round(cpu[inst], 2))
            )
            cons_rows.append(
                (
                    f"{g:g} g",
                    inst,
                    round(nees["turn"]["mean"], 2),
                    round(nees["turn"]["in_band"], 2),
                    round(nees["straight"]["mean"], 2),
                    round(nees["straight"]["in_band"], 2),
                    round(nis["turn"]["mean"], 2),
                    round(nis["straight"]["mean"], 2),
                    round(rms["turn"]),
                    round(rms["straight"]),
                )
            )
            figs[f"{tag}/{inst}"] = {
                "runs": n,
                "held_one_id": held,
                "held_ci95": [lo, hi],
                "mean_ids_per_target": ids,
                "nees": nees,
                "nis": nis,
                "pos_rms_m": rms,
                "cpu_s_per_run": cpu[inst],
            }
    return hold_rows, cons_rows, figs


def dense_clutter() -> tuple[list[tuple[Any, ...]], dict[str, Any]]:
    sc = scenario("dense_clutter")
    res, cpu = run_all(sc, {e.instance: n_runs(N_DENSE) for e in sc.estimators})
    rows, figs = [], {}
    for inst, per_run in res.items():
        started = [sum(1 for v in r["track_ids_per_target"].values() if v) for r in per_run]
        final = [sum(r["final_matched"]) for r in per_run]
        false = [r["false_confirmed_tracks"] for r in per_run]
        ms = cpu[inst] / per_run[0]["n_scans"] * 1e3
        rows.append(
            (
                inst,
                len(per_run),
                float(np.mean(started)),
                min(started),
                float(np.mean(final)),
                float(np.mean(false)),
                round(ms),
            )
        )
        figs[inst] = {
            "runs": len(per_run),
            "targets_started": started,
            "final": final,
            "false": false,
            "cpu_ms_per_scan": ms,
        }
    return rows, figs


def crossing() -> tuple[list[tuple[Any, ...]], dict[str, Any]]:
    sc = scenario("crossing")
    res, _ = run_all(sc, {e.instance: n_runs(N_CROSSING) for e in sc.estimators})
    rows, figs = [], {}
    for inst, per_run in res.items():
        agg = mc.aggregate(per_run)
        keys = (
            "id_switches_per_run",
            "id_swaps_per_run",
            "id_restarts_per_run",
            "fragmentations_per_run",
            "breaks_per_run",
            "assignment_changes_per_run",
            "gospa_mean_m",
            "gospa_missed_per_scan",
            "gospa_false_per_scan",
        )
        rows.append((inst, agg["n_runs"], *(round(agg[k], 2) for k in keys)))
        figs[inst] = {k: agg[k] for k in keys} | {
            "n_runs": agg["n_runs"],
            "runs_with_a_swap": sum(r["id_swaps"] > 0 for r in per_run),
        }
    return rows, figs


def paper_stream() -> tuple[list[tuple[Any, ...]], dict[str, Any]]:
    sc = scenario("paper")
    res, _ = run_all(sc, {e.instance: n_runs(N_PAPER_STREAM) for e in sc.estimators})
    rows, figs = [], {}
    for inst, per_run in res.items():
        one = sum(r["n_tracks_created"] == 1 and r["final_matched"][0] for r in per_run)
        last = [math.sqrt(r["pos_sq_err_m2"][-1]) for r in per_run if r["final_matched"][0]]
        rows.append(
            (inst, f"{one}/{len(per_run)}", round(float(np.max(last))), round(math.sqrt(np.mean(np.square(last)))))
        )
        figs[inst] = {"runs": len(per_run), "one_id": one, "final_err_max_m": float(np.max(last))}
    return rows, figs


def paper_accuracy() -> tuple[list[tuple[Any, ...]], dict[str, Any]]:
    truth = paper_truth()
    times = np.arange(51) * 3.0
    z, sig = noisy_plots(truth, np.random.default_rng(2024), n_runs(N_PAPER_LOOP))
    out: dict[str, Any] = {}
    for name, cfg in (("paper", PclTrackerConfig.paper()), ("default", PclTrackerConfig())):
        r = run_single_target(z, sig, times, cfg)
        out[name] = (
            rmse_over_runs(r.x[:, :, :3] - truth[None, :, :3]),
            rmse_over_runs(r.x[:, :, 3:] - truth[None, :, 3:]),
        )
    rows = []
    for i, t in enumerate(TABLE_A_T):
        k = t // 3
        rows.append(
            (
                t,
                TABLE_A_POS[i],
                round(float(out["paper"][0][k]), 1),
                round(float(out["default"][0][k]), 1),
                TABLE_A_VEL[i],
                round(float(out["paper"][1][k]), 2),
                round(float(out["default"][1][k]), 2),
            )
        )
    figs = {n: {"pos_rmse_m": v[0].tolist(), "vel_rmse_mps": v[1].tolist()} for n, v in out.items()}
    return rows, figs


def main() -> None:
    figures: dict[str, Any] = {"scale": SCALE}
    rows, figures["paper_accuracy"] = paper_accuracy()
    emit(
        "pcl_robust_paper_accuracy",
        ["t s", "Table A pos", "paper pos", "default pos", "Table A vel", "paper vel", "default vel"],
        rows,
        {"paper_accuracy": figures["paper_accuracy"]},
    )
    rows, figures["paper_stream"] = paper_stream()
    emit(
        "pcl_robust_paper_stream",
        ["estimator", "one id, tracked at end", "max final err m", "RMS final err m"],
        rows,
        {"paper_stream": figures["paper_stream"]},
    )
    hold, cons, figures["manoeuvres"] = manoeuvres()
    emit(
        "pcl_robust_manoeuvre_hold",
        ["turn", "estimator", "runs with one id", "95 % CI", "ids per target", "CPU s/run"],
        hold,
        {"manoeuvres": figures["manoeuvres"]},
    )
    emit(
        "pcl_robust_manoeuvre_consistency",
        [
            "turn",
            "estimator",
            "NEES turn",
            "in band",
            "NEES straight",
            "in band",
            "NIS turn",
            "NIS straight",
            "pos RMS turn m",
            "pos RMS straight m",
        ],
        cons,
        {},
    )
    rows, figures["crossing"] = crossing()
    emit(
        "pcl_robust_crossing",
        [
            "estimator",
            "runs",
            "ID switches",
            "swaps",
            "restarts",
            "fragmentations",
            "breaks",
            "former id_swaps",
            "GOSPA m",
            "missed/scan",
            "false/scan",
        ],
        rows,
        {"crossing": figures["crossing"]},
    )
    rows, figures["dense_clutter"] = dense_clutter()
    emit(
        "pcl_robust_dense_clutter",
        [
            "estimator",
            "runs",
            "targets with a confirmed track (of 100)",
            "min",
            "tracked at the end",
            "false confirmed/run",
            "CPU ms/scan",
        ],
        rows,
        {"dense_clutter": figures["dense_clutter"]},
    )
    emit("pcl_robust", ["part"], [(k,) for k in figures], figures)


if __name__ == "__main__":
    main()
