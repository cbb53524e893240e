"""PCL tracker (digest 003): statistical tests S1–S7 of §4.2 on the paper scenario.

The digest's numbers come from 1,000 Monte-Carlo runs; the default run here uses ``N_DEFAULT`` runs and the
``slow`` tests the full 1,000 with the digest's own tolerances.

Monte-Carlo tolerance reasoning (default N): an RMSE estimated from N runs has a relative standard error of
at most 1/sqrt(2N) (error dominated by one Gaussian axis: the MSE is sigma^2 chi2_1 / N, relative SE
sqrt(2/N), halved for the square root), and the digest's references carry their own MC error of the same
kind for 1,000 runs. The relative tolerance used with N runs is therefore
``max(digest tolerance, 3 * sqrt(1/(2N) + 1/2000))`` (11.6 % for N = 500). Counts and means use their own
binomial / chi-square standard errors, stated where used. Everything is deterministic for the fixed seed.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import pytest

from services.pcl_tracker.config import PclTrackerConfig
from services.pcl_tracker.experiments import LoopResult, rmse_over_runs, run_single_target
from services.pcl_tracker.filter import convert_plots
from services.pcl_tracker.simulation import noisy_plots, paper_scenario, paper_truth, true_bistatic

SEED = 2024
N_DEFAULT = 500
N_FULL = 1000
TX = (8000.0, 0.0, 300.0)
TIMES = np.arange(51) * 3.0

# digest Table A: t -> (single-plot conversion, proposed q=0.01 pos, vel, proposed q=0 pos, vel)
TABLE_A = {
    3: (182, 182, 58.9, 182, 58.9),
    6: (182, 145, 29.4, 145, 29.4),
    9: (189, 128, 20.8, 128, 20.8),
    12: (187, 114, 14.7, 114, 14.7),
    15: (196, 104, 10.7, 104, 10.7),
    21: (212, 93, 6.7, 93, 6.7),
    30: (232, 83, 4.1, 83, 4.1),
    36: (220, 79, 3.3, 79, 3.3),
    42: (187, 69, 2.6, 69, 2.6),
    45: (163, 59, 2.4, 59, 2.4),
    48: (141, 52, 2.1, 52, 2.1),
    51: (134, 45, 1.9, 45, 1.9),
    60: (116, 38, 1.6, 38, 1.5),
    75: (125, 40, 1.3, 40, 1.2),
    90: (142, 44, 1.1, 43, 1.0),
    105: (174, 48, 1.0, 46, 0.8),
    120: (208, 53, 1.0, 47, 0.7),
    135: (232, 58, 1.0, 49, 0.6),
    150: (269, 63, 1.0, 51, 0.5),
}


def rel_tol(n_runs: int, digest_tol: float) -> float:
    """Relative tolerance for an RMSE from n_runs runs vs a 1,000-run reference (module docstring)."""
    if n_runs >= N_FULL:
        return digest_tol
    return max(digest_tol, 3.0 * math.sqrt(1.0 / (2 * n_runs) + 1.0 / (2 * N_FULL)))


def idx(t: float) -> int:
    return round(t / 3.0)


@cache
def plots(n_runs: int) -> tuple[np.ndarray, np.ndarray]:
    z, sig = noisy_plots(paper_truth(TIMES), np.random.default_rng(SEED), n_runs)
    return z, sig


@cache
def loop(n_runs: int, init_cov: str, q: float, gating: bool, bistatic: bool = False) -> LoopResult:
    z, sig = plots(n_runs)
    cfg = paper_scenario().tracker_config(preset="paper", init_cov=init_cov, q_accel_var_m2s4=q)
    return run_single_target(z, sig, TIMES, cfg, gating=gating, bistatic_output=bistatic)


def pos_vel_rmse(r: LoopResult) -> tuple[np.ndarray, np.ndarray]:
    truth = paper_truth(TIMES)
    mask = r.alive
    return (
        rmse_over_runs(r.x[..., :3] - truth[None, :, :3], mask),
        rmse_over_runs(r.x[..., 3:] - truth[None, :, 3:], mask),
    )


# ------------------------------------------------------------------------------------------------ S1
def check_s1(n: int) -> None:
    z, sig = plots(n)
    truth = paper_truth(TIMES)
    tol = rel_tol(n, 0.05)
    for t, row in TABLE_A.items():
        k = idx(t)
        conv = convert_plots(z[:, k, :3], np.broadcast_to(sig[:3], (n, 3)), np.array(TX))
        rmse = math.sqrt(float(np.mean(np.sum((conv.y - truth[k, :3]) ** 2, axis=1))))
        assert rmse == pytest.approx(row[0], rel=tol), f"t={t}"


def test_s1_single_plot_conversion_rmse() -> None:
    check_s1(N_DEFAULT)


@pytest.mark.slow
def test_s1_single_plot_conversion_rmse_full() -> None:
    check_s1(N_FULL)


# ------------------------------------------------------------------------------------------------ S2, S3
def check_s2_s3(n: int) -> None:
    tol = rel_tol(n, 0.10)
    pos, vel = pos_vel_rmse(loop(n, "paper_diagonal", 0.01, False))
    for t, row in TABLE_A.items():
        assert pos[idx(t)] == pytest.approx(row[1], rel=tol), f"pos t={t}"
        assert vel[idx(t)] == pytest.approx(row[2], rel=tol), f"vel t={t}"
    # the paper's claims (< 50 m, 1-2 m/s) as the digest words them, widened by the same MC allowance
    w = 1.0 + rel_tol(n, 0.0)
    late = TIMES >= 51.0
    assert np.all(pos[(TIMES >= 51.0) & (TIMES <= 120.0)] <= 55.0 * w)
    assert np.all(pos[late] <= 65.0 * w)
    assert np.all(vel[late] <= 2.0 * w) and np.all(vel[late] >= 0.8 / w)
    pos_q, _ = pos_vel_rmse(loop(n, "paper_diagonal", 0.001, False))
    assert np.all(pos_q[late] <= 55.0 * w)
    # q = 0 columns of Table A
    pos0, vel0 = pos_vel_rmse(loop(n, "paper_diagonal", 0.0, False))
    for t, row in TABLE_A.items():
        assert pos0[idx(t)] == pytest.approx(row[3], rel=tol), f"pos q=0 t={t}"
        assert vel0[idx(t)] == pytest.approx(row[4], rel=max(tol, 0.05 / row[4])), f"vel q=0 t={t}"


def test_s2_s3_proposed_position_and_velocity_rmse() -> None:
    check_s2_s3(N_DEFAULT)


@pytest.mark.slow
def test_s2_s3_proposed_position_and_velocity_rmse_full() -> None:
    check_s2_s3(N_FULL)


# ------------------------------------------------------------------------------------------------ S4
def col_mean(a: np.ndarray) -> np.ndarray:
    """Mean over runs of the finite entries of each scan (NaN where a scan has none)."""
    ok = np.isfinite(a)
    n = ok.sum(axis=0)
    return np.where(n > 0, np.where(ok, a, 0.0).sum(axis=0) / np.maximum(n, 1), np.nan)


def nees(r: LoopResult) -> np.ndarray:
    e = r.x - paper_truth(TIMES)[None]
    P = np.where(r.alive[..., None, None], r.P, np.eye(6))
    v = np.einsum("rti,rti->rt", e, np.linalg.solve(P, e[..., None])[..., 0])
    return np.where(r.alive, v, np.nan)


def check_s4(n: int, init_cov: str) -> None:
    r = loop(n, init_cov, 0.0, True)
    mean_nees = col_mean(nees(r))[2:]
    mean_nis = col_mean(r.nis)[3:]
    out = ~r.in_gate
    has_plot = ~np.isnan(r.nis)
    frac_out = out.sum(axis=0) / np.maximum(has_plot.sum(axis=0), 1)
    # digest bounds for 1,000 runs; with fewer runs widen by 3 SE of a mean of N chi2 variables
    # (chi2_6: SE = sqrt(12 / N); chi2_4: SE = sqrt(8 / N)) measured from the reference ranges, and the
    # outside-gate fraction by 3 binomial SE at p = 1 %.
    full = n >= N_FULL
    if init_cov == "full":
        lo, hi = (5.5, 6.6) if full else (5.78 - 3 * math.sqrt(12 / n), 6.25 + 3 * math.sqrt(12 / n))
        scan3_max = 0.015 if full else 0.005 + 3 * math.sqrt(0.005 * 0.995 / n)
    else:
        lo, hi = (5.0, 6.6) if full else (5.43 - 3 * math.sqrt(12 / n), 6.35 + 3 * math.sqrt(12 / n))
        scan3_max = 0.035 if full else 0.027 + 3 * math.sqrt(0.027 * 0.973 / n)
    nis_lo, nis_hi = (3.3, 4.5) if full else (3.5 - 3 * math.sqrt(8 / n), 4.22 + 3 * math.sqrt(8 / n))
    per_scan_max = 0.025 if full else 0.01 + 3 * math.sqrt(0.01 * 0.99 / n)
    avg_max = 0.013 if full else 0.01 + 3 * math.sqrt(0.01 * 0.99 / (n * 48))
    assert np.all((mean_nees >= lo) & (mean_nees <= hi)), mean_nees
    assert np.all((mean_nis >= nis_lo) & (mean_nis <= nis_hi)), mean_nis
    assert np.all(frac_out[3:] <= per_scan_max), frac_out
    assert float(out[:, 3:].sum() / has_plot[:, 3:].sum()) <= avg_max
    assert frac_out[2] <= scan3_max


@pytest.mark.parametrize("init_cov", ["full", "paper_diagonal"])
def test_s4_consistency(init_cov: str) -> None:
    check_s4(N_DEFAULT, init_cov)


@pytest.mark.slow
@pytest.mark.parametrize("init_cov", ["full", "paper_diagonal"])
def test_s4_consistency_full(init_cov: str) -> None:
    check_s4(N_FULL, init_cov)


# ------------------------------------------------------------------------------------------------ S5
def _h_b_ref(x: np.ndarray) -> np.ndarray:
    """Digest §6 h_b written out again (independent of the package)."""
    p, v = x[:3], x[3:]
    t = np.array(TX)
    R = np.linalg.norm(p)
    d = p - t
    Rt = np.linalg.norm(d)
    return np.array([R + Rt - np.linalg.norm(t), math.atan2(p[0], p[1]), math.asin(p[2] / R), p @ v / R + d @ v / Rt])


def crlb_position(used: str) -> np.ndarray:
    """3-D position RMS bound (m) per scan for a CV target with q = 0 (digest Table D).

    Fisher information of x0 (state at t = 0) from plots up to scan k, H_k = dh/dx(t_k) F(t_k),
    bound at t_k = F(t_k) J^-1 F(t_k)^T. ``used``: "all" (every component every scan) or "as_used"
    (angles of plot 1, all four components of plot 2, then r_b, a, e).
    """
    c = math.radians(256.0)
    x0 = np.array([9000.0, 5000.0, 1000.0, 200 * math.sin(c), 200 * math.cos(c), 0.0])
    sig = np.array([200.0, math.radians(0.5), math.radians(0.5), 5.0])
    J = np.zeros((6, 6))
    out = np.full(len(TIMES), np.nan)
    for k, t in enumerate(TIMES):
        F = np.eye(6)
        F[:3, 3:] = t * np.eye(3)
        x = F @ x0
        H = np.zeros((4, 6))
        for i in range(6):
            h = 1e-4 * max(abs(x[i]), 1.0)
            e = np.zeros(6)
            e[i] = h
            d = _h_b_ref(x + e) - _h_b_ref(x - e)
            H[:, i] = d / (2 * h)
        rows = [0, 1, 2, 3]
        if used == "as_used":
            rows = [1, 2] if k == 0 else ([0, 1, 2, 3] if k == 1 else [0, 1, 2])
        Hk = H[rows] @ F
        J += Hk.T @ np.diag(1.0 / sig[rows] ** 2) @ Hk
        if k >= 1:
            C = F @ np.linalg.inv(J) @ F.T
            out[k] = math.sqrt(np.trace(C[:3, :3]))
    return out


def test_crlb_computation_reproduces_digest_table_d() -> None:
    as_used = crlb_position("as_used")
    allm = crlb_position("all")
    for t, a, u in ((3, 145, 180), (6, 124, 147), (15, 92, 105), (30, 75, 83), (45, 52, 59), (60, 30, 37)):
        assert allm[idx(t)] == pytest.approx(a, rel=0.02)
        assert as_used[idx(t)] == pytest.approx(u, rel=0.02)
    for t, u in ((45, 58.6), (48, 50.6), (51, 44.3), (60, 36.7), (90, 42.4), (120, 46.6), (150, 50.2)):
        assert as_used[idx(t)] == pytest.approx(u, rel=0.01)


def check_s5(n: int) -> None:
    pos, _ = pos_vel_rmse(loop(n, "paper_diagonal", 0.0, True))
    as_used = crlb_position("as_used")
    allm = crlb_position("all")
    late = TIMES >= 45.0
    up = 1.0 + rel_tol(n, 0.08)
    down = 1.0 - rel_tol(n, 0.05)
    assert np.all(pos[late] <= as_used[late] * up), pos[late] / as_used[late]
    assert np.all(pos[late] >= allm[late] * down), pos[late] / allm[late]


def test_s5_efficiency_against_the_crlb() -> None:
    check_s5(N_DEFAULT)


@pytest.mark.slow
def test_s5_efficiency_against_the_crlb_full() -> None:
    check_s5(N_FULL)


# ------------------------------------------------------------------------------------------------ S6
def check_s6(n: int, init_cov: str) -> None:
    r = loop(n, init_cov, 0.01, True)
    kept = float(np.mean(r.drop_index < 0))
    # digest: >= 99.0 % (full, reference 99.8 %) / >= 97.5 % (diagonal, reference 98.8 %) of 1,000 runs.
    # With N runs: reference drop rate + 3 binomial SE.
    if n >= N_FULL:
        need = 0.99 if init_cov == "full" else 0.975
    else:
        p = 0.002 if init_cov == "full" else 0.012
        need = min(0.99 if init_cov == "full" else 0.975, 1.0 - p - 3 * math.sqrt(p * (1 - p) / n))
    assert kept >= need
    drops = TIMES[r.drop_index[r.drop_index >= 0]]
    assert np.all(drops <= 30.0)  # drops cluster early (digest: at t ~ 12 s)


@pytest.mark.parametrize("init_cov", ["full", "paper_diagonal"])
def test_s6_track_continuity(init_cov: str) -> None:
    check_s6(N_DEFAULT, init_cov)


@pytest.mark.slow
@pytest.mark.parametrize("init_cov", ["full", "paper_diagonal"])
def test_s6_track_continuity_full(init_cov: str) -> None:
    check_s6(N_FULL, init_cov)


# ------------------------------------------------------------------------------------------------ S7
def check_s7(n: int, init_cov: str) -> None:
    from services.pcl_tracker.geometry import h_b

    r = loop(n, init_cov, 0.01, False)
    zt = true_bistatic(paper_truth(TIMES), TX)
    zf = h_b(np.nan_to_num(r.x), np.array(TX))  # h_b(x_a(k|k)) as the digest writes it
    err = zf - zt[None]
    vb_bias = np.mean(err[:, 2:, 3], axis=0)
    vb_sd = np.std(err[:, 2:, 3], axis=0)
    vb_rmse = np.sqrt(np.mean(err[:, 2:, 3] ** 2, axis=0))
    rb_rmse = np.sqrt(np.mean(err[:, 2:, 0] ** 2, axis=0))
    # bias: the digest's bound (0.6 full / 1.5 diagonal) sits within ~1 SE of its own reference at scan 3
    # (v_b sd ~7-8 m/s there), so the bound is the reference + 3 SE of a mean of N runs per scan.
    ref = 0.31 if init_cov == "full" else 1.23
    crit = 0.6 if init_cov == "full" else 1.5
    bound = np.maximum(crit, ref + 3.0 * vb_sd / math.sqrt(n))
    assert np.all(np.abs(vb_bias) <= bound), np.abs(vb_bias) - bound
    w = 1.0 + rel_tol(n, 0.0)
    assert np.all(vb_rmse <= 9.0 * w)
    assert rb_rmse[0] <= 160.0 * w
    assert np.all(rb_rmse[1:] <= 125.0 * w)


@pytest.mark.parametrize("init_cov", ["full", "paper_diagonal"])
def test_s7_bistatic_output_accuracy(init_cov: str) -> None:
    check_s7(N_DEFAULT, init_cov)


@pytest.mark.slow
@pytest.mark.parametrize("init_cov", ["full", "paper_diagonal"])
def test_s7_bistatic_output_accuracy_full(init_cov: str) -> None:
    check_s7(N_FULL, init_cov)


def test_config_defaults_are_the_digest_values() -> None:
    cfg = PclTrackerConfig.paper()
    t = cfg.tracker
    assert (t.q_accel_var_m2s4, t.init_L, t.confirm_M, t.drop_K) == (0.01, 2, 0, 3)
    assert (t.ring_vmin_mps, t.ring_vmax_mps, t.ring_gate_prob, t.assoc_gate_prob) == (30.0, 400.0, 0.99, 0.99)
    assert t.gamma4 == pytest.approx(13.28, abs=0.005) and t.gamma3 == pytest.approx(11.34, abs=0.005)
    assert (t.init_cov, t.association, t.measurement_model) == ("full", "gnn", "converted_position")
    lim = cfg.limits
    assert (lim.rb_min_convertible_m, lim.max_gap_scans, lim.reorder_window_scans) == (600.0, 10, 1)
    assert cfg.default_sigmas()[0] == 200.0 and cfg.geometry.doppler_sign == -1
