"""PCL tracker (digest 003): the core-level parts of the end-to-end tests E1–E5 of §4.4, plus a many-target case.

Every run goes through :class:`PclTracker.step` with ``BistaticScan`` messages from the simulation, as the
service will (the Zenoh variant comes with the service adapter). The default run uses fewer runs than
the digest; rates are then checked against the digest's reference rate minus 3 binomial standard errors
(stated per test), and the ``slow`` tests use the digest's run counts and thresholds.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import pytest

from schemas.pcl_tracker import PclScanReport
from services.pcl_tracker.core import PclTracker
from services.pcl_tracker.metrics import aggregate, run_metrics
from services.pcl_tracker.simulation import (
    SimRun,
    clutter_scenario,
    many_target_scenario,
    paper_scenario,
    simulate,
)

N_E1, N_E1_FULL = 50, 1000
N_E3, N_E3_FULL = 50, 200
N_E5, N_E5_FULL = 10, 100


def rate_bound(p_ref: float, n: int, floor: float) -> float:
    """Digest threshold ``floor`` for its own run count, or p_ref - 3 binomial SE for n runs if lower."""
    return min(floor, p_ref - 3.0 * math.sqrt(p_ref * (1.0 - p_ref) / n))


@cache
def run_paper(seed: int, confirm_m: int = 0, confirm_n: int = 0, drop: tuple[int, ...] = ()) -> tuple:
    sc = paper_scenario(drop_scans=drop)
    run = simulate(sc, np.random.default_rng(seed))
    trk = PclTracker(
        sc.tracker_config(preset="paper", init_cov="full", confirm_M=confirm_m, confirm_N=confirm_n, drop_K=3)
    )
    reps: list[PclScanReport] = [r for s in run.scans for r in trk.step(s)]
    return run, reps


def ids_created(reps: list[PclScanReport]) -> set[int]:
    return {t.track_id for r in reps for t in r.tracks}


def final_error(run: SimRun, reps: list[PclScanReport]) -> float:
    last = reps[-1]
    errs = [
        float(np.linalg.norm(np.array(t.estimate.mean[:3]) - run.true_states[-1, 0, :3]))
        for t in last.tracks
        if t.status == "CONFIRMED"
    ]
    return min(errs) if errs else math.inf


# ------------------------------------------------------------------------------------------------ E1, E2
def check_e1(n: int) -> None:
    good = 0
    worst = 0.0
    for seed in range(n):
        run, reps = run_paper(seed)
        assert len(reps) == 51 and [r.scan_id for r in reps] == list(range(1, 52))
        single = ids_created(reps) == {1}
        first = [t for t in reps[1].tracks if t.track_id == 1]
        ok = (
            single
            and len(first) == 1
            and first[0].status == "CONFIRMED"
            and first[0].created_scan_id == 2
            and all(t.status == "CONFIRMED" for r in reps[1:] for t in r.tracks)
        )
        good += ok
        err = final_error(run, reps)
        worst = max(worst, err)
        assert err < 250.0, (seed, err)  # 100 % of runs (reference max 149 m over 1,000 runs)
    # reference 982/1000
    assert good / n >= rate_bound(0.982, n, 0.97), good
    assert worst < 250.0


def test_e1_single_target_stream() -> None:
    check_e1(N_E1)


@pytest.mark.slow
def test_e1_single_target_stream_full() -> None:
    check_e1(N_E1_FULL)


def test_e2_m_of_n_confirmation_changes_only_the_label() -> None:
    n = N_E1 // 2
    clean = 0
    for seed in range(n):
        _, base = run_paper(seed)
        _, mn = run_paper(seed, 3, 4)
        early_hits = all(
            t.associated_plot_id is not None for r in base[2:5] for t in r.tracks if t.track_id == 1
        ) and ids_created(base[:5]) == {1}
        if not early_hits:
            continue
        clean += 1
        status = [next(t.status for t in r.tracks if t.track_id == 1) for r in mn[1:5]]
        assert status == ["TENTATIVE", "TENTATIVE", "TENTATIVE", "CONFIRMED"], (seed, status)
        for a, b in zip(base, mn, strict=True):
            sa = {t.track_id: t.estimate.mean for t in a.tracks}
            sb = {t.track_id: t.estimate.mean for t in b.tracks}
            assert sa == sb, seed
    # runs whose first three plots after creation are all in the gate: about 0.99^3 of them
    assert clean >= rate_bound(0.97, n, 0.97) * n


# ------------------------------------------------------------------------------------------------ E3, E4
def check_e3(n: int) -> None:
    kept = 0
    for seed in range(n):
        _, reps = run_paper(seed, drop=(20, 21))
        coast = [next((t for t in reps[k - 1].tracks if t.track_id == 1), None) for k in (20, 21)]
        survived = all(c is not None and c.status == "CONFIRMED" and c.coasted for c in coast)
        if survived:
            assert [c.consecutive_misses for c in coast] == [1, 2]  # type: ignore[union-attr]
            assert all("coasted" in c.flags for c in coast)  # type: ignore[union-attr]
        final = [t.track_id for t in reps[-1].tracks if t.status == "CONFIRMED"]
        kept += survived and final == [1]
    # reference 196/200
    assert kept / n >= rate_bound(0.98, n, 0.97), kept


def test_e3_two_missing_plots_are_coasted() -> None:
    check_e3(N_E3)


@pytest.mark.slow
def test_e3_two_missing_plots_are_coasted_full() -> None:
    check_e3(N_E3_FULL)


def test_e4_three_missing_plots_drop_and_reinitiate() -> None:
    n = 20
    checked = 0
    for seed in range(n):
        _, reps = run_paper(seed, drop=(20, 21, 22))
        if ids_created(reps[:19]) != {1}:
            continue  # a re-initiation happened before the gap (E1's ~2 %): not this test's subject
        checked += 1
        r22 = reps[21]
        assert r22.scan_id == 22 and r22.t_s == pytest.approx(63.0)
        dropped = [t for t in r22.tracks if t.track_id == 1]
        assert len(dropped) == 1 and dropped[0].status == "DROPPED" and dropped[0].drop_reason == "K_misses"
        assert all(t.track_id != 1 for r in reps[22:] for t in r.tracks)
        assert not reps[22].tracks  # scan 23: first plot after the gap is only a candidate
        new = [t for t in reps[23].tracks]
        assert len(new) == 1 and new[0].track_id == 2 and new[0].created_scan_id == 24
    assert checked >= n - 2


# ------------------------------------------------------------------------------------------------ E5
@cache
def run_clutter(seed: int, m: int, n: int) -> tuple[SimRun, list[PclScanReport]]:
    sc = clutter_scenario()
    run = simulate(sc, np.random.default_rng(1000 + seed))
    trk = PclTracker(sc.tracker_config(preset="paper", confirm_M=m, confirm_N=n, association="gnn"))
    return run, [r for s in run.scans for r in trk.step(s)]


def check_e5(runs: int) -> None:
    false_per_run = {}
    for m, n in ((0, 0), (2, 4), (3, 4)):
        metrics = []
        for seed in range(runs):
            run, reps = run_clutter(seed, m, n)
            metrics.append(run_metrics(reps, run.true_states, [s.scan_id for s in run.scans]))
            assert all(r.n_cholesky_fallbacks == 0 for r in reps)
        agg = aggregate(metrics)
        false_per_run[m] = agg["false_confirmed_tracks_per_run"]
        # reference 100/100 for M = 0 and M/N = 3/4
        assert agg["final_track_fraction"] >= rate_bound(0.995, runs, 0.95), (m, agg["final_track_fraction"])
    # digest: about 0.85 false pairs pass the ring gate per scan -> ~42 false confirmed tracks per run
    # with M = 0 (reference figure, checked to +-25 %), <= 0.1 with M/N = 3/4, non-increasing in M
    assert 0.75 * 42 <= false_per_run[0] <= 1.25 * 42, false_per_run
    assert false_per_run[3] <= 0.1
    assert false_per_run[0] >= false_per_run[2] >= false_per_run[3]


def test_e5_clutter_and_false_track_control() -> None:
    check_e5(N_E5)


@pytest.mark.slow
def test_e5_clutter_and_false_track_control_full() -> None:
    check_e5(N_E5_FULL)


# ------------------------------------------------------------------------------------------------ many targets [E]
def _h_a3_ref(z: np.ndarray, tx: np.ndarray) -> np.ndarray:
    """Digest §1.4 compact form, written again here: R_r = r_b (r_b + 2L) / (2 (r_b + L - u.t))."""
    rb, az, el = z[..., 0], z[..., 1], z[..., 2]
    u = np.stack([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)], axis=-1)
    L = np.linalg.norm(tx)
    Rr = rb * (rb + 2 * L) / (2 * (rb + L - u @ tx))
    return Rr[..., None] * u


def test_many_targets_in_clutter() -> None:
    """20 targets (8 turning), P_d = 0.95, 10 clutter plots per scan, GNN, M/N = 3/4, q = 10 [E].

    Not a digest test: the reference is computed here. A tracker that works must beat the single-plot
    conversion (its OSPA after acquisition stays below the RMS error of converting each true plot on its
    own), keep every target (matched track at the last scan) without id swaps, and confirm no clutter.
    """
    sc = many_target_scenario(20)
    tx = np.array(sc.tx_position_enu_m)
    metrics, conv_sq = [], []
    for seed in range(3):
        run = simulate(sc, np.random.default_rng(seed))
        trk = PclTracker(sc.tracker_config(preset="paper", q_accel_var_m2s4=10.0, confirm_M=3, confirm_N=4))
        reps = [r for s in run.scans for r in trk.step(s)]
        metrics.append(run_metrics(reps, run.true_states, [s.scan_id for s in run.scans]))
        for k, s in enumerate(run.scans):
            for p in s.plots:
                who = run.plot_origin[k][p.plot_id]
                if who < 0:
                    continue
                z = np.array([p.bistatic_range_m, math.radians(p.azimuth_deg), math.radians(p.elevation_deg)])
                conv_sq.append(float(np.sum((_h_a3_ref(z, tx) - run.true_states[k, who, :3]) ** 2)))
    agg = aggregate(metrics)
    conv_rms = math.sqrt(float(np.mean(conv_sq)))
    late_ospa = float(np.mean(agg["ospa_mean_m_per_scan"][9:]))
    assert late_ospa < 0.8 * conv_rms, (late_ospa, conv_rms)
    assert agg["final_track_fraction"] >= 0.95
    assert agg["id_swaps_per_run"] <= 1.0
    assert agg["false_confirmed_tracks_per_run"] <= 1.0
    assert agg["coverage"] >= 0.85
