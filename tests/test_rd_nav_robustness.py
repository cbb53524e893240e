"""Digest 002 §6.4 (T-ROB-1..12): the estimator under injected faults. T-ROB-13 is in test_rd_nav_core.py.

Default run: a few runs of 15 min to 2 h per case (the digest uses 20-30 runs of 4 h); the full-size
versions are behind ``@pytest.mark.slow``. Standard-error reasoning as in test_rd_nav_nominal.py: with
>= 700 cycles the RMS is known to ~3 %, a p99 to ~10 %; maxima of fewer samples are not larger on average.
Where a per-run effect dominates (node-coordinate errors, sound-speed bias), the default uses more,
shorter runs, because each run contributes one draw of the bias.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from services.rd_nav.config import RdNavConfig
from services.rd_nav.offline import RunLog, monte_carlo, run
from services.rd_nav.simulation import ref

MC = {"propagated_fix_period_s": 0.0, "emit_propagated_after_cycle": False}
OUTSIDE_PATTERN_S = 7600.0


def mc(scn: Any, runs: int, seed0: int, **core: Any) -> tuple[dict[str, Any], list[RunLog]]:
    return monte_carlo(scn, runs, seed0, RdNavConfig(**MC, **core))


def errors(log: RunLog) -> np.ndarray:
    a = np.array(log.auv["auv4"].pf)
    return np.hypot(a[:, 1] - a[:, 6], a[:, 2] - a[:, 7])


# ------------------------------------------------------------------------------------------ T-ROB-1 ----
def test_t_rob_1_motion_compensation_and_negative_control() -> None:
    """T-ROB-1: compensation on: RMS <= 0.70 m; the same data with compensation off: RMS > 3 m.

    The off-build is the negative control: it shows the test detects a missing compensation (the
    prototype: 0.566 vs 4.83 m). Paired runs (same seeds, same simulated data).
    """
    on, _ = mc(ref("inside", duration_s=1800.0), 2, 5000)
    off, _ = mc(ref("inside", duration_s=1800.0), 2, 5000, motion_compensation=False)
    assert on["pf"]["rms_m"] <= 0.70, on["pf"]
    assert off["pf"]["rms_m"] > 3.0, off["pf"]


# ------------------------------------------------------------------------------------ T-ROB-2, -3 ----
def test_t_rob_2_multipath_inside() -> None:
    """T-ROB-2: 5 % of arrivals late by U(2, 50) ms: RMS <= 1.0, p99 <= 3.5, max <= 15 m; in no run the
    error over the last 10 cycles exceeds 5 m.

    Re-toleranced p99 for the default 3 x 1 h: the p99 is set by rare moderate outliers (5-10 m on one
    d_j pass the gate; with M = 2 they are undetectable but for the prior), so it varies from run to run
    (SD ~0.65 m per 1 h run measured over 6 runs, pooled 3.03 m; prototype 2.87 m over 30 x 4 h). With 3
    runs its standard error is ~0.35 m; the default limit is 3.5 + 2 SE = 4.2 m. The slow test keeps 3.5.
    """
    agg, logs = mc(ref("inside", duration_s=3600.0, multipath_prob=0.05), 3, 5100)
    p = agg["pf"]
    assert p["rms_m"] <= 1.0 and p["p99_m"] <= 4.2 and p["max_m"] <= 15.0, p
    for lg in logs:
        assert errors(lg)[-10:].max() <= 5.0


def test_t_rob_3_multipath_outside() -> None:
    """T-ROB-3: the same faults on the outside lawnmower: RMS <= 1.6, p99 <= 4.5, max <= 20 m.

    Default 2 passes over the pattern. Measured over 6 passes: pooled p99 3.74 m, per-pass SD 0.45 m, so
    the p99 of 2 passes has a standard error of ~0.32 m: default limit 4.5 + 2 SE = 5.1 m (slow test: 4.5).
    """
    agg, _ = mc(ref("outside", duration_s=OUTSIDE_PATTERN_S, multipath_prob=0.05), 2, 5200)
    p = agg["pf"]
    assert p["rms_m"] <= 1.6 and p["p99_m"] <= 5.1 and p["max_m"] <= 20.0, p


# ------------------------------------------------------------------------------------------ T-ROB-4 ----
def test_t_rob_4_packet_loss() -> None:
    """T-ROB-4: 20 % independent loss of every packet at the AUV: RMS <= 1.1, p99 <= 3.7, max <= 12 m;
    partial (M = 1) cycles are used, leader-less replies dropped, nothing crashes.

    Default 2 x 1 h (720 cycles): RMS expected ~0.85 (+-0.04); p99 ~3.1 (+-0.3) against 3.7.
    """
    agg, logs = mc(ref("inside", duration_s=3600.0, packet_loss=0.2), 2, 5300)
    p = agg["pf"]
    assert p["rms_m"] <= 1.1 and p["p99_m"] <= 3.7 and p["max_m"] <= 12.0, p
    assert agg["rejected_inputs"].get("no_leader", 0) > 0
    assert sum(lg.auv["auv4"].cycle_status["PARTIAL"] for lg in logs) > 50
    # the stricter loss model (followers can miss the leader too) must not crash or diverge either
    strict, _ = mc(ref("inside", duration_s=1800.0, packet_loss=0.2, loss_at_followers=True), 1, 5310)
    assert strict["pf"]["max_m"] <= 20.0 and strict["reinit_total"] <= 5


# ------------------------------------------------------------------------------------------ T-ROB-5 ----
def blackout_run(seed: int, t0: float, t1: float, end: float) -> dict[str, float]:
    log = run(
        ref("inside", duration_s=end, blackouts=[(t0, t1)]),
        seed,
        RdNavConfig(propagated_fix_period_s=10.0, emit_propagated_after_cycle=False),
    )
    lg = log.auv["auv4"]
    prop = np.array([p[:3] for p in lg.propagated])
    k = int(np.searchsorted(prop[:, 0], t1)) - 1
    a = np.array(lg.pf)
    e = errors(log)
    after = e[a[:, 0] > t1]
    below = np.flatnonzero(after < 1.5)
    return {
        "sqrt_trQ_end": float(prop[k, 2]),
        "err_end": float(prop[k, 1]),
        "cycles_to_1p5": float(below[0]) if below.size else np.inf,
        "max_after_30": float(after[30:].max()),
        "reinit": float(log.cores["auv4"].reinit_count),
    }


def test_t_rob_5_acoustic_blackout() -> None:
    """T-ROB-5: 600 s blackout: sqrt(trace Q) at its end >= 10 m; error < 1.5 m within 40 cycles in every
    run; max error from 30 cycles after the blackout to the end <= 3 m.

    Default: 3 runs, blackout 1200-1800 s, end at 2700 s. The digest's "within 10 cycles in >= 80 % of
    runs" (prototype 18/20) cannot be resolved with 3 runs: with p = 0.9 per run, requiring all 3 would
    fail 27 % of the time; the default asks for >= 2 of 3 (fails with probability 2.8 % if p = 0.9).
    """
    res = [blackout_run(5400 + i, 1200.0, 1800.0, 2700.0) for i in range(3)]
    for r in res:
        assert r["sqrt_trQ_end"] >= 10.0, r
        assert r["cycles_to_1p5"] <= 40, r
        assert r["max_after_30"] <= 3.0, r
    assert sum(r["cycles_to_1p5"] <= 10 for r in res) >= 2, res


# ------------------------------------------------------------------------------------------ T-ROB-6 ----
def test_t_rob_6_clock_step_inside_a_cycle() -> None:
    """T-ROB-6: +0.5 s receiver-clock step between the leader and follower arrivals of one cycle: that
    cycle is rejected, no re-initialisation, RMS within 2 % of the nominal run (paired: same seeds)."""
    step, _ = mc(ref("inside", duration_s=3600.0, clock_steps=[(1802.0, 0.5)]), 2, 1000)
    nominal, _ = mc(ref("inside", duration_s=3600.0), 2, 1000)
    assert step["rejected_cycles"].get("CLOCK_JUMP", 0) == 2  # one per run
    assert step["reinit_total"] == 0
    assert abs(step["pf"]["rms_m"] / nominal["pf"]["rms_m"] - 1.0) <= 0.02


# ------------------------------------------------------------------------------------------ T-ROB-7 ----
def test_t_rob_7_receiver_clock_skew() -> None:
    """T-ROB-7: 20 ppm receiver skew: per-axis |mean| <= 0.15 m, RMS <= 0.70 m.

    720 cycles: the per-axis mean has a standard error of ~0.025 m; the expected bias is ~0.09 m.
    """
    agg, _ = mc(ref("inside", duration_s=3600.0, clock_skew_ppm=20.0), 2, 5700)
    p = agg["pf"]
    assert abs(p["mean_x_m"]) <= 0.15 and abs(p["mean_y_m"]) <= 0.15 and p["rms_m"] <= 0.70, p


# ------------------------------------------------------------------------------------------ T-ROB-8 ----
def test_t_rob_8_undersized_process_noise() -> None:
    """T-ROB-8: q_rel = 0.02, q_abs = 0.05 m, no drift term: with gating + re-init RMS <= 1.0, max <= 8 m, re-inits > 0;
    without them the filter diverges (the digest's prototype: RMS 95 m), shown here as RMS > 5 m."""
    # the digest's white process noise (process_model paper), every term undersized
    small = {"process_model": "paper", "q_rel": 0.02, "q_abs_m": 0.05, "q_drift_mps": 0.0}
    agg, _ = mc(ref("inside", duration_s=3600.0), 2, 5800, **small)
    p = agg["pf"]
    assert p["rms_m"] <= 1.0 and p["max_m"] <= 8.0, p
    assert agg["reinit_total"] > 0
    bare, _ = mc(ref("inside", duration_s=3600.0), 1, 5800, gating=False, reinit=False, **small)
    assert bare["pf"]["rms_m"] > 5.0, bare["pf"]


# ------------------------------------------------------------------------------------------ T-ROB-9 ----
def test_t_rob_9_node_coordinate_errors() -> None:
    """T-ROB-9: node coordinates wrong by N(0, 0.5 m) per axis, unknown to the filter: RMS <= 1.3, max <= 5 m.

    The error is a per-run bias (one draw of the node errors per run), so the default uses 16 runs of
    7.5 min. Measured over 24 runs: pooled RMS 1.28 m (prototype 1.12 m over 30), per-run RMS^2 SD ~1.0 m^2,
    so the pooled RMS of 16 runs has a standard error of ~0.10 m: default limit 1.3 + 2 SE = 1.5 m.
    """
    agg, _ = mc(ref("inside", duration_s=450.0, node_error_sigma_m=0.5), 16, 5900)
    p = agg["pf"]
    assert p["rms_m"] <= 1.5 and p["max_m"] <= 5.0, p


# ----------------------------------------------------------------------------------------- T-ROB-10 ----
def test_t_rob_10_follower_reply_jitter() -> None:
    """T-ROB-10: follower detection/reply jitter sigma_f = 0.2 ms (in R too): RMS <= 0.75 m."""
    agg, _ = mc(ref("inside", duration_s=3600.0, sigma_f_s=0.2e-3), 2, 6000, sigma_f_s=0.2e-3)
    assert agg["pf"]["rms_m"] <= 0.75, agg["pf"]


# ----------------------------------------------------------------------------------------- T-ROB-11 ----
def test_t_rob_11_sound_speed_bias() -> None:
    """T-ROB-11: constant +1.5 m/s sound-speed bias: the estimator shows a north bias of 2.1 +- 0.4 m.

    The bias is deterministic given the track (linearised value 2.0 m at the centroid, T-MM-9); 4 x 15 min.
    """
    agg, _ = mc(ref("inside", duration_s=900.0, c_bias_mps=1.5), 4, 6100)
    assert agg["pf"]["mean_x_m"] == pytest.approx(2.1, abs=0.4), agg["pf"]


# ----------------------------------------------------------------------------------------- T-ROB-12 ----
def racetrack_checks(logs: list[RunLog]) -> dict[str, float]:
    steps, mx, e2, n = [], 0.0, 0.0, 0
    alias = np.array([2424.99, 1500.0])
    for lg in logs:
        a = np.array(lg.auv["auv4"].pf)
        ev = a[:, 1:3] - a[:, 6:8]
        e = np.hypot(ev[:, 0], ev[:, 1])
        steps.append(float(np.max(np.hypot(*np.diff(ev, axis=0).T))))
        mx = max(mx, float(e.max()))
        e2 += float(np.sum(e * e))
        n += e.size
        # never closer to the alias region near A1 than to the truth while beyond the apex
        beyond = a[:, 6] > 3000.0
        d_alias = np.hypot(*(a[beyond, 1:3] - alias).T)
        assert (d_alias > e[beyond]).all()
    return {"max_step_m": max(steps), "max_m": mx, "rms_m": float(np.sqrt(e2 / n))}


def test_t_rob_12_alias_region_racetrack() -> None:
    """T-ROB-12: racetrack to 1.5 km beyond the apex: no jump to the alias, largest change of the error
    between cycles <= 20 m, max |e| <= 40 m, RMS <= 10 m (default: one 75 min lap)."""
    _, logs = mc(ref("racetrack", duration_s=4500.0), 1, 6200)
    r = racetrack_checks(logs)
    assert r["max_step_m"] <= 20.0 and r["max_m"] <= 40.0 and r["rms_m"] <= 10.0, r


# ------------------------------------------------------------------------------ full size (slow) ----
@pytest.mark.slow
def test_t_rob_full_sizes() -> None:
    """T-ROB-1..11 at the digest's sizes (20-30 runs of 4 h; blackout 20 runs)."""
    on, _ = mc(ref("inside"), 20, 20_000)
    off, _ = mc(ref("inside"), 20, 20_000, motion_compensation=False)
    assert on["pf"]["rms_m"] <= 0.70 and off["pf"]["rms_m"] > 3.0
    p = mc(ref("inside", multipath_prob=0.05), 30, 21_000)[0]["pf"]
    assert p["rms_m"] <= 1.0 and p["p99_m"] <= 3.5 and p["max_m"] <= 15.0
    p = mc(ref("outside", multipath_prob=0.05), 30, 22_000)[0]["pf"]
    assert p["rms_m"] <= 1.6 and p["p99_m"] <= 4.5 and p["max_m"] <= 20.0
    p = mc(ref("inside", packet_loss=0.2), 30, 23_000)[0]["pf"]
    assert p["rms_m"] <= 1.1 and p["p99_m"] <= 3.7 and p["max_m"] <= 12.0
    res = [blackout_run(24_000 + i, 3600.0, 4200.0, 14_400.0) for i in range(20)]
    assert all(r["sqrt_trQ_end"] >= 10.0 and r["cycles_to_1p5"] <= 40 and r["max_after_30"] <= 3.0 for r in res)
    assert sum(r["cycles_to_1p5"] <= 10 for r in res) >= 16
    step, _ = mc(ref("inside", clock_steps=[(7202.0, 0.5)]), 30, 25_000)
    nominal, _ = mc(ref("inside"), 30, 25_000)
    assert step["reinit_total"] == 0 and abs(step["pf"]["rms_m"] / nominal["pf"]["rms_m"] - 1.0) <= 0.02
    p = mc(ref("inside", clock_skew_ppm=20.0), 30, 26_000)[0]["pf"]
    assert abs(p["mean_x_m"]) <= 0.15 and abs(p["mean_y_m"]) <= 0.15 and p["rms_m"] <= 0.70
    agg = mc(ref("inside"), 30, 27_000, process_model="paper", q_rel=0.02, q_abs_m=0.05, q_drift_mps=0.0)[0]
    assert agg["pf"]["rms_m"] <= 1.0 and agg["pf"]["max_m"] <= 8.0 and agg["reinit_total"] > 0
    p = mc(ref("inside", node_error_sigma_m=0.5), 30, 28_000)[0]["pf"]
    assert p["rms_m"] <= 1.3 and p["max_m"] <= 5.0
    assert mc(ref("inside", sigma_f_s=0.2e-3), 30, 29_000, sigma_f_s=0.2e-3)[0]["pf"]["rms_m"] <= 0.75
    assert mc(ref("inside", c_bias_mps=1.5), 30, 30_000)[0]["pf"]["mean_x_m"] == pytest.approx(2.1, abs=0.4)


@pytest.mark.slow
def test_t_rob_12_full_size() -> None:
    """T-ROB-12 at the digest's size (20 x 2 h): max step <= 20 m, max <= 40 m, RMS <= 10 m."""
    r = racetrack_checks(mc(ref("racetrack"), 20, 31_000)[1])
    assert r["max_step_m"] <= 20.0 and r["max_m"] <= 40.0 and r["rms_m"] <= 10.0
