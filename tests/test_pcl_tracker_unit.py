"""PCL tracker (digest 003): the deterministic unit tests U1–U12 of §4.1, with the digest's numbers.

Expected values come from the digest's tables or from formulas written out independently in this file.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from services.pcl_tracker.config import PclTrackerConfig
from services.pcl_tracker.core import PclTracker
from services.pcl_tracker.geometry import (
    angle_rates,
    baseline,
    bistatic_angle,
    h_a3,
    h_a6,
    h_a6_quotient,
    h_b,
)
from services.pcl_tracker.initiation import bistatic_to_cartesian, ring_ellipse_test, two_plot_bistatic_estimate
from services.pcl_tracker.models import cv_process_noise, cv_transition
from services.pcl_tracker.simulation import scan_from_bistatic
from shared.filters.angles import wrap_pi
from shared.filters.unscented import sigma_points, unscented_transform

TX = np.array([8000.0, 0.0, 300.0])
D2R = math.pi / 180.0
SIG = np.array([200.0, 0.5 * D2R, 0.5 * D2R, 5.0])
NS = 1_000_000_000


def truth_state(t: float) -> np.ndarray:
    """Paper target (digest §3.1), written out independently of the simulation module."""
    c = 256.0 * D2R
    v = np.array([200.0 * math.sin(c), 200.0 * math.cos(c), 0.0])
    return np.concatenate([np.array([9000.0, 5000.0, 1000.0]) + v * t, v])


# ------------------------------------------------------------------------------------------------ U1
# digest §3.2: t, r_b, alpha deg, eps deg, v_b, alpha_dot deg/s, eps_dot deg/s, bistatic angle deg
TABLE_32 = [
    (0.0, 7485.301, 60.9454, 5.5477, -276.9396, -0.28909, 0.10342, 49.3),
    (3.0, 6685.983, 60.0265, 5.8755, -255.4548, -0.32452, 0.11544, None),
    (30.0, 2889.428, 41.8496, 11.8555, -35.2279, -1.35038, 0.40026, 94.0),
    (60.0, 6384.387, -51.5776, 16.5079, 297.6103, -2.69148, -0.56422, 29.7),
    (90.0, 17035.787, -85.6401, 6.7178, 380.3583, -0.42515, -0.14882, 4.8),
    (150.0, 40462.360, -96.4059, 2.8292, 395.2533, -0.07484, -0.02767, 2.3),
]


def test_u1_forward_transform_matches_the_digest_truth_table() -> None:
    assert baseline(TX) == pytest.approx(8005.623, abs=5e-4)
    for t, rb, az, el, vb, azd, eld, beta in TABLE_32:
        z = h_b(truth_state(t), TX)
        assert z[0] == pytest.approx(rb, abs=0.01)
        assert math.degrees(z[1]) == pytest.approx(az, abs=1e-4)
        assert math.degrees(z[2]) == pytest.approx(el, abs=1e-4)
        assert z[3] == pytest.approx(vb, abs=1e-4)
        ad, ed = angle_rates(truth_state(t))
        assert math.degrees(float(ad)) == pytest.approx(azd, abs=1e-5)
        assert math.degrees(float(ed)) == pytest.approx(eld, abs=1e-5)
        if beta is not None:
            assert math.degrees(float(bistatic_angle(truth_state(t)[:3], TX))) == pytest.approx(beta, abs=0.05)


def test_u1_positions_of_the_truth_table() -> None:
    p = truth_state(3.0)[:3]
    np.testing.assert_allclose(p, [8417.823, 4854.847, 1000.0], atol=5e-4)
    np.testing.assert_allclose(truth_state(150.0)[:3], [-20108.872, -2257.657, 1000.0], atol=5e-4)


# ------------------------------------------------------------------------------------------------ U2
def test_u2_inverse_position_round_trip_on_random_targets() -> None:
    rng = np.random.default_rng(3)
    n = 30_000
    R = rng.uniform(50.0, 200_000.0, n)
    az = rng.uniform(-math.pi, math.pi, n)
    el = rng.uniform(-5.0 * D2R, 85.0 * D2R, n)
    p = R[:, None] * np.stack([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)], axis=-1)
    zb = h_b(np.concatenate([p, np.zeros_like(p)], axis=-1), TX)
    keep = zb[:, 0] > 100.0
    p, zb = p[keep][:10_000], zb[keep][:10_000]
    assert len(p) == 10_000
    back, clamped, valid = h_a3(zb[:, :3], TX)
    assert valid.all() and not clamped.any()
    assert float(np.max(np.linalg.norm(back - p, axis=1))) < 1e-6


# ------------------------------------------------------------------------------------------------ U3, U4
def _exact_xb(t: float) -> np.ndarray:
    x = truth_state(t)
    z = h_b(x, TX)
    ad, ed = angle_rates(x)
    return np.array([z[0], z[3], z[1], ad, z[2], ed])


def test_u3_inverse_state_transform_recovers_the_velocity() -> None:
    for t in (0.0, 3.0, 30.0, 60.0, 90.0, 150.0):
        xa, _, valid = h_a6(_exact_xb(t), TX)
        assert bool(valid)
        np.testing.assert_allclose(xa[3:], truth_state(t)[3:], atol=1e-6)
        np.testing.assert_allclose(xa[:3], truth_state(t)[:3], atol=1e-6)
    xa0, _, _ = h_a6(_exact_xb(0.0), TX)
    np.testing.assert_allclose(xa0[3:], [-194.059, -48.384, 0.0], atol=5e-4)


def test_u4_paper_quotient_rule_equals_the_compact_form() -> None:
    rng = np.random.default_rng(4)
    xb = np.stack(
        [
            rng.uniform(200.0, 100_000.0, 500),
            rng.uniform(-500.0, 500.0, 500),
            rng.uniform(-math.pi, math.pi, 500),
            rng.uniform(-0.05, 0.05, 500),
            rng.uniform(-0.05, 1.4, 500),
            rng.uniform(-0.02, 0.02, 500),
        ],
        axis=-1,
    )
    a, _, _ = h_a6(xb, TX)
    b = h_a6_quotient(xb, TX)
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * np.abs(b).max())


# ------------------------------------------------------------------------------------------------ U5
def test_u5_ut_is_exact_on_linear_maps_with_2n_equal_weight_points() -> None:
    rng = np.random.default_rng(5)
    for n in (3, 4, 6):
        m = rng.normal(size=(2, n)) * 100.0
        A0 = rng.normal(size=(n, n))
        P = np.stack([A0 @ A0.T + np.eye(n), np.diag(rng.uniform(0.5, 2.0, n))])
        A = rng.normal(size=(4, n))
        b = rng.normal(size=4)
        X = sigma_points(m, P)
        assert X.shape == (2, 2 * n, n)
        res = unscented_transform(m, P, lambda x, A=A, b=b: x @ A.T + b)
        np.testing.assert_allclose(res.mean, m @ A.T + b, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(res.cov, A @ P @ A.T, rtol=1e-9, atol=1e-9)
        # equal weights 1/(2n): the UT mean of any f is the plain average over the 2n points
        f = lambda x: np.sin(x[..., :2]) * 3.0 + x[..., 1:3] ** 2  # noqa: E731
        np.testing.assert_allclose(unscented_transform(m, P, f).mean, f(X).mean(axis=1), rtol=1e-12)
        # the points are m +- sqrt(n) columns of the Cholesky factor
        D = np.linalg.cholesky(P)
        np.testing.assert_allclose(X[:, :n, :] - m[:, None, :], math.sqrt(n) * np.swapaxes(D, 1, 2), atol=1e-9)
        np.testing.assert_allclose(X[:, n:, :] - m[:, None, :], -math.sqrt(n) * np.swapaxes(D, 1, 2), atol=1e-9)


# ------------------------------------------------------------------------------------------------ U6
def test_u6_ut_azimuth_wrap_is_rotation_invariant() -> None:
    x = np.array([-30.0, -20_000.0, 1_000.0, 120.0, 40.0, 0.0])
    P = np.diag([1000.0**2, 1000.0**2, 100.0**2, 20.0**2, 20.0**2, 5.0**2])
    tx = np.array([5000.0, 3000.0, 200.0])
    th = -math.pi / 2  # rotate the whole scene about z by -90 deg
    Rz = np.array([[math.cos(th), -math.sin(th), 0.0], [math.sin(th), math.cos(th), 0.0], [0.0, 0.0, 1.0]])
    T = np.zeros((6, 6))
    T[:3, :3] = T[3:, 3:] = Rz
    a = unscented_transform(x[None], P[None], lambda s: h_b(s, tx), az_index=1)
    b = unscented_transform((T @ x)[None], (T @ P @ T.T)[None], lambda s: h_b(s, Rz @ tx), az_index=1)
    d_az = float(wrap_pi(b.mean[0, 1] - a.mean[0, 1] - math.pi / 2))
    assert abs(d_az) < 1e-9
    for i in (0, 2, 3):
        assert b.mean[0, i] == pytest.approx(a.mean[0, i], rel=1e-9, abs=1e-9)
    np.testing.assert_allclose(b.cov[0], a.cov[0], rtol=1e-9, atol=1e-9 * np.abs(a.cov[0]).max())
    # the case really straddles +-180 deg: without wrapping the mean is far off (digest: about -150 deg)
    naive = unscented_transform(x[None], P[None], lambda s: h_b(s, tx), az_index=None)
    assert abs(math.degrees(float(wrap_pi(naive.mean[0, 1] - a.mean[0, 1])))) > 10.0
    assert math.degrees(math.sqrt(a.cov[0, 1, 1])) < 10.0 < math.degrees(math.sqrt(naive.cov[0, 1, 1]))


# ------------------------------------------------------------------------------------------------ U7
def test_u7_two_plot_initialisation_without_noise() -> None:
    z1 = h_b(truth_state(0.0), TX)[None]
    z2 = h_b(truth_state(3.0), TX)[None]
    sig = SIG[None]
    xb, Pb = two_plot_bistatic_estimate(z1, sig, z2, sig, np.array([3.0]), "full")
    assert math.degrees(xb[0, 3]) == pytest.approx((60.0265 - 60.9454) / 3.0, abs=5e-5)
    xa, _, _ = h_a6(xb[0], TX)
    np.testing.assert_allclose(xa[:3], truth_state(3.0)[:3], atol=1e-6)
    np.testing.assert_allclose(xa[3:], [-191.005, -50.189, -0.878], atol=5e-3)
    assert float(np.linalg.norm(xa[3:] - truth_state(3.0)[3:])) == pytest.approx(3.65, abs=0.01)
    # P_b(2): paper diagonal vs full (cross terms sigma^2 / tau)
    _, Pd = two_plot_bistatic_estimate(z1, sig, z2, sig, np.array([3.0]), "paper_diagonal")
    assert np.count_nonzero(Pd[0] - np.diag(np.diag(Pd[0]))) == 0
    assert Pb[0, 2, 3] == pytest.approx(SIG[1] ** 2 / 3.0)
    assert Pb[0, 4, 5] == pytest.approx(SIG[2] ** 2 / 3.0)
    assert Pb[0, 3, 3] == pytest.approx(2.0 * SIG[1] ** 2 / 9.0)


# ------------------------------------------------------------------------------------------------ U8
def test_u8_ring_gate_and_its_ellipse_augmentation() -> None:
    gamma3 = chi2.ppf(0.99, 3)
    assert gamma3 == pytest.approx(11.34, abs=0.005)
    v_min, v_max, tau = 30.0, 400.0, 3.0
    tiny = np.eye(3) * 1e-6  # chi2 alone would reject everything: inside the ring it must not be used
    z1 = np.array([1000.0, 2000.0, 500.0])
    inside = z1 + np.array([300.0, 400.0, 0.0])  # 500 m in [90, 1200]
    ok, s, rho = ring_ellipse_test(z1, tiny, inside, tiny, np.array(3.0), v_min, v_max, gamma3)
    assert bool(ok) and float(s) == 0.0 and float(rho) == 0.0
    # outside the outer circle: rho uses z_m = z_c(1) + R_max e_12 (computed here by hand)
    R1 = np.diag([150.0**2, 80.0**2, 60.0**2])
    R2 = np.diag([120.0**2, 90.0**2, 50.0**2])
    for extra, expect in ((250.0, True), (600.0, False)):
        e = np.array([0.6, 0.8, 0.0])
        z2 = z1 + (v_max * tau + extra) * e
        z_m = z1 + v_max * tau * e
        r = z2 - z_m
        rho_hand = float(r @ np.linalg.solve(R1 + R2, r))
        ok, s, rho = ring_ellipse_test(z1, R1, z2, R2, np.array(tau), v_min, v_max, gamma3)
        assert float(s) == 1.0
        assert float(rho) == pytest.approx(rho_hand, rel=1e-12)
        assert bool(ok) == expect == (rho_hand < gamma3)
    # inside the inner circle: z_m on the inner circle along the same line
    z2 = z1 + np.array([0.0, 10.0, 0.0])
    z_m = z1 + v_min * tau * np.array([0.0, 1.0, 0.0])
    rho_hand = float((z2 - z_m) @ np.linalg.solve(R1 + R2, z2 - z_m))
    ok, s, rho = ring_ellipse_test(z1, R1, z2, R2, np.array(tau), v_min, v_max, gamma3)
    assert float(s) == -1.0 and float(rho) == pytest.approx(rho_hand) and bool(ok) == (rho_hand < gamma3)


# ------------------------------------------------------------------------------------------------ core helpers
def true_z(t: float) -> np.ndarray:
    return h_b(truth_state(t), TX)


def scan(k: int, rows: list[np.ndarray] | np.ndarray, ids: list[str] | None = None) -> object:
    """Scan number k (1-based) at t = 3 (k - 1) s."""
    return scan_from_bistatic(k, (k - 1) * 3 * NS, np.asarray(rows).reshape(-1, 4), plot_ids=ids)


def noisy_z(rng: np.random.Generator, t: float) -> np.ndarray:
    z = true_z(t) + rng.standard_normal(4) * SIG
    z[1] = wrap_pi(z[1])
    return z


def run_core(tracker: PclTracker, scans: list[object]) -> list:
    out = []
    for s in scans:
        out.extend(tracker.step(s))  # type: ignore[arg-type]
    return out


def tracks_of(rep) -> dict[int, object]:  # type: ignore[no-untyped-def]
    return {t.track_id: t for t in rep.tracks}


# ------------------------------------------------------------------------------------------------ U9
def test_u9_coasting_and_drop_after_k_misses() -> None:
    cfg = PclTrackerConfig.paper().with_tracker(drop_K=3)
    rng = np.random.default_rng(9)
    trk = PclTracker(cfg)
    reps = run_core(trk, [scan(k, [noisy_z(rng, 3.0 * (k - 1))]) for k in range(1, 11)])
    last = tracks_of(reps[-1])[1]
    assert last.status == "CONFIRMED"
    F = cv_transition(3.0)[0]
    Q = cv_process_noise(3.0, cfg.tracker.q_accel_var_m2s4)[0]
    x, P = np.array(last.estimate.mean), np.array(last.estimate.covariance)
    for k, misses in ((11, 1), (12, 2)):
        rep = trk.step(scan(k, []))[0]  # type: ignore[arg-type]
        tr = tracks_of(rep)[1]
        x, P = F @ x, F @ P @ F.T + Q
        assert tr.status == "CONFIRMED" and tr.coasted and tr.consecutive_misses == misses
        np.testing.assert_allclose(tr.estimate.mean, x, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(tr.estimate.covariance, P, rtol=1e-9, atol=1e-9)
    rep = trk.step(scan(13, []))[0]  # type: ignore[arg-type]
    dropped = [t for t in rep.tracks if t.track_id == 1]
    assert len(dropped) == 1 and dropped[0].status == "DROPPED" and dropped[0].drop_reason == "K_misses"
    rep = trk.step(scan(14, []))[0]  # type: ignore[arg-type]
    assert all(t.track_id != 1 for t in rep.tracks)  # emitted once


def test_u9_a_hit_after_two_misses_resets_the_counter() -> None:
    rng = np.random.default_rng(19)
    trk = PclTracker(PclTrackerConfig.paper())
    scans = [scan(k, [noisy_z(rng, 3.0 * (k - 1))]) for k in range(1, 11)]
    scans += [scan(11, []), scan(12, []), scan(13, [noisy_z(rng, 36.0)]), scan(14, []), scan(15, [])]
    reps = run_core(trk, scans)
    after_hit = tracks_of(reps[12])[1]
    assert after_hit.consecutive_misses == 0 and after_hit.associated_plot_id is not None
    final = tracks_of(reps[-1])[1]
    assert final.status == "CONFIRMED" and final.consecutive_misses == 2


# ------------------------------------------------------------------------------------------------ U10
def test_u10_m_zero_confirms_at_creation() -> None:
    trk = PclTracker(PclTrackerConfig.paper().with_tracker(confirm_M=0))
    reps = run_core(trk, [scan(1, [true_z(0.0)]), scan(2, [true_z(3.0)])])
    tr = tracks_of(reps[-1])[1]
    assert tr.status == "CONFIRMED" and tr.created_scan_id == 2 and "initiated" in tr.flags


def _mn_run(pattern: list[bool]) -> list:
    trk = PclTracker(PclTrackerConfig.paper().with_tracker(confirm_M=3, confirm_N=4, drop_K=3))
    scans = [scan(1, [true_z(0.0)]), scan(2, [true_z(3.0)])]
    for i, hit in enumerate(pattern):
        k = 3 + i
        scans.append(scan(k, [true_z(3.0 * (k - 1))] if hit else []))
    return run_core(trk, scans)


def test_u10_m_of_n_confirms_on_the_third_hit_in_the_window() -> None:
    reps = _mn_run([True, True, False, True])
    status = [tracks_of(r)[1].status for r in reps[1:]]
    assert status == ["TENTATIVE", "TENTATIVE", "TENTATIVE", "TENTATIVE", "CONFIRMED"]
    assert tracks_of(reps[3])[1].confirm_progress == [2, 2]


def test_u10_m_of_n_deletes_as_soon_as_m_is_unreachable() -> None:
    reps = _mn_run([True, False, False])
    assert tracks_of(reps[3])[1].status == "TENTATIVE"  # +2: hits 1, 2 scans, 2 left: 3 still reachable
    final = tracks_of(reps[4])[1]  # +3: 1 hit + 1 scan left < 3
    assert final.status == "DROPPED" and final.drop_reason == "MN_failed"


# ------------------------------------------------------------------------------------------------ U11
def test_u11_two_of_l_with_l_3_pairs_within_two_scans_only() -> None:
    cfg = PclTrackerConfig.paper().with_tracker(init_L=3)
    trk = PclTracker(cfg)
    reps = run_core(trk, [scan(1, [true_z(0.0)]), scan(2, []), scan(3, [true_z(6.0)])])
    assert [len(r.tracks) for r in reps] == [0, 0, 1]
    tr = reps[-1].tracks[0]
    # tau_2 is the actual time difference (6 s): same state as the two-plot estimate computed directly
    xb, Pb = two_plot_bistatic_estimate(
        true_z(0.0)[None], SIG[None], true_z(6.0)[None], SIG[None], np.array([6.0]), "full"
    )
    ref = bistatic_to_cartesian(xb, Pb, TX)
    np.testing.assert_allclose(tr.estimate.mean, ref.mean[0], rtol=1e-9, atol=1e-6)
    # a plot 3 scans later is outside the 2/3 window
    trk = PclTracker(cfg)
    reps = run_core(trk, [scan(1, [true_z(0.0)]), scan(2, []), scan(3, []), scan(4, [true_z(9.0)])])
    assert all(len(r.tracks) == 0 for r in reps)
    # L = 2 (default): one empty scan in between already breaks the pair
    trk = PclTracker(PclTrackerConfig.paper())
    reps = run_core(trk, [scan(1, [true_z(0.0)]), scan(2, []), scan(3, [true_z(6.0)])])
    assert all(len(r.tracks) == 0 for r in reps)


# ------------------------------------------------------------------------------------------------ U12
def test_u12_a_plot_in_a_track_gate_never_starts_a_track() -> None:
    trk = PclTracker(PclTrackerConfig.paper())
    rng = np.random.default_rng(12)
    scans = [scan(k, [noisy_z(rng, 3.0 * (k - 1))]) for k in range(1, 6)]
    # from scan 6 on: the true plot and a twin 100 m further in r_b (inside the gate, loses the GNN)
    for k in range(6, 16):
        z = noisy_z(rng, 3.0 * (k - 1))
        twin = z + np.array([100.0, 0.0, 0.0, 1.0])
        scans.append(scan(k, [z, twin], ["a", "b"]))
    reps = run_core(trk, scans)
    for r in reps[5:]:
        assert r.n_candidates == 0 and r.n_initiated == 0
        assert {t.track_id for t in r.tracks} == {1}
        assert r.tracks[0].n_plots_in_gate == 2
    assert trk.next_track_id == 2
