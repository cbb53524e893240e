"""The default configuration (preset robust) beyond the paper's case (issue 15), small-N versions.

The full-size figures come from ``python -m bench pcl_robust`` (docs/pcl_tracker.md); these runs are small
enough for the default test run, so each assertion states the statistical argument for its threshold:

* manoeuvres (``scenarios/pcl_tracker_manoeuvre_{2g,05g}.yaml``): the issue's target is one track id per
  target in >= 95 % of runs. With n runs and at most one run lost, a true rate of 80 % would pass with
  probability P(Bin(n, 0.8) >= n - 1) (0.069 for n = 20, 0.38 for n = 10), so 19/20 at 2 g is evidence of a
  high rate, 9/10 at 0.5 g a check of the same mechanism on a long, gentle turn; the paper's configuration
  restarts the target (the issue: every run), checked on a few runs;
* dense clutter (1,000 clutter plots per scan, every scan a burst): tracks start for the targets (the paper's
  rule starts none), on one run of 30 targets over 12 scans; a target misses initiation only if its plot is
  out of the 500 strongest on two consecutive scans or undetected, so >= 90 % is a loose bound;
* the paper scenario: the default's RMSE is no worse than the digest's Table A (q = 0.01) beyond the Monte-Carlo
  tolerance of ``test_pcl_tracker_stats`` (the paper accuracy is not lost), and it keeps the track as S6 asks;
* crossing targets (``scenarios/pcl_tracker_crossing.yaml``): nobody swaps in the truth, so the identity
  score of a tracker that keeps its ids must be ~0 swaps; the former per-scan count is not.
"""

from __future__ import annotations

import math
from functools import cache
from typing import Any

import numpy as np
from conftest import REPO
from test_pcl_tracker_stats import TABLE_A, rel_tol

from services.pcl_tracker import mc
from services.pcl_tracker.config import PclTrackerConfig
from services.pcl_tracker.core import PclTracker
from services.pcl_tracker.experiments import rmse_over_runs, run_single_target
from services.pcl_tracker.metrics import run_metrics
from services.pcl_tracker.simulation import (
    ClutterSpec,
    SnrSpec,
    many_target_scenario,
    noisy_plots,
    paper_truth,
    simulate,
)
from services.player.scenario import Scenario, load_scenario
from services.player.timeline import scenario_events

N_PAPER = 500


@cache
def scenario(name: str) -> Scenario:
    return load_scenario(REPO / "scenarios" / f"pcl_tracker_{name}.yaml")


def mc_runs(name: str, instance: str, n: int) -> list[dict[str, Any]]:
    sc = scenario(name)
    est = next(e for e in sc.estimators if e.instance == instance)
    return [mc.run_core(scenario_events(sc, run=r), dict(est.params), sc) for r in range(n)]


def held(r: dict[str, Any]) -> bool:
    """One track id for the target over the whole run, and tracked at the last scan."""
    return len(r["track_ids_per_target"]["0"]) == 1 and bool(r["final_matched"][0])


def test_default_holds_a_2g_turn_and_the_paper_configuration_does_not() -> None:
    runs = mc_runs("manoeuvre_2g", "rx1-fm", 20)
    assert sum(held(r) for r in runs) >= 19  # binomial argument in the module doc
    paper = mc_runs("manoeuvre_2g", "rx1-fm-paper", 4)
    assert sum(held(r) for r in paper) == 0  # the issue: the paper's q = 0.01 restarts a turning target
    assert all(len(r["track_ids_per_target"]["0"]) >= 2 for r in paper)


def test_default_holds_a_half_g_turn() -> None:
    runs = mc_runs("manoeuvre_05g", "rx1-fm", 10)
    assert sum(held(r) for r in runs) >= 9


def test_dense_clutter_still_starts_tracks() -> None:
    sc = many_target_scenario(
        30,
        seed=7,
        n_scans=12,
        p_detection=0.9,
        clutter=ClutterSpec(rate_per_scan=1000.0, rb_range_m=(0.0, 150_000.0)),
        snr=SnrSpec("swerling1", 13.0, 20.0, 10.0),
    )
    run = simulate(sc, np.random.default_rng(4))
    started = {}
    for preset in ("robust", "paper"):
        trk = PclTracker(sc.tracker_config(preset=preset, confirm_M=3, confirm_N=4))
        reps = [r for s in run.scans for r in trk.step(s)]
        assert all("clutter_burst" in r.flags for r in reps)  # > 500 plots: every scan is a burst
        m = run_metrics(reps, run.true_states, [s.scan_id for s in run.scans])
        started[preset] = sum(1 for v in m["track_ids_per_target"].values() if v)
    assert started["paper"] == 0  # the issue: no track is ever started
    assert started["robust"] >= 27  # >= 90 % of 30 targets


def test_paper_accuracy_is_not_lost() -> None:
    truth = paper_truth()
    times = np.arange(51) * 3.0
    z, sig = noisy_plots(truth, np.random.default_rng(2024), N_PAPER)
    r = run_single_target(z, sig, times, PclTrackerConfig())
    pos = rmse_over_runs(r.x[:, :, :3] - truth[None, :, :3])
    vel = rmse_over_runs(r.x[:, :, 3:] - truth[None, :, 3:])
    tol = rel_tol(N_PAPER, 0.10)  # the digest's ±10 % (S2/S3), widened by the Monte-Carlo error of N runs
    for t, (_, p_ref, v_ref, _, _) in TABLE_A.items():
        k = t // 3
        assert pos[k] <= p_ref * (1.0 + tol), (t, pos[k], p_ref)
        assert vel[k] <= v_ref * (1.0 + tol), (t, vel[k], v_ref)
    assert max(pos[17:41]) <= 55.0 and max(pos[17:]) <= 65.0  # the paper's claim (S2) on [51, 120] s and to 150 s
    gated = run_single_target(z, sig, times, PclTrackerConfig(), gating=True)
    kept = float(np.mean(gated.drop_index < 0))
    assert kept >= 0.99 - 3.0 * math.sqrt(0.99 * 0.01 / N_PAPER)  # S6 (full P_b) threshold, minus 3 binomial SE


def test_crossing_targets_are_scored_without_false_swaps() -> None:
    runs = mc_runs("crossing", "rx1-fm", 6)
    agg = mc.aggregate(runs)
    assert agg["id_swaps_per_run"] <= 0.5  # true swaps: 0; a tracker that exchanged ids would score >= 2 per swap
    assert agg["coverage"] >= 0.8  # the targets are tracked at all (else 0 swaps would be vacuous)
    for r in runs:
        assert r["id_switches"] == r["id_swaps"] + r["id_restarts"]
