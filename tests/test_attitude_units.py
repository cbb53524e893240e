"""Deterministic unit tests of the attitude estimator (digest 004, §4.1 U1-U14, and the building blocks).

Expected numbers are the digest's; where it prints a value to d decimals the tolerance is one unit of the last
printed digit (the digest's "1e-6 relative" cannot apply to rounded printouts). Other references are computed
independently here (closed-form FSF covariances, filterpy's Kalman filter, finite differences).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from services.attitude.angles import AngleConventions, angle_block, angle_jacobian, angles_of_states, attitude_angles
from services.attitude.config import AttitudeConfig, MeasurementSigmas
from services.attitude.filter import predict, update
from services.attitude.geometry import (
    body_axes,
    conversion_jacobian,
    convert_plot,
    los_matrix,
    spherical_to_cartesian,
)
from services.attitude.initiation import fsf_design, fsf_estimate, quadratic_state
from services.attitude.models import H_POS, jerk_input, process_noise, transition, transition_axis
from services.attitude.offline import monte_carlo_size
from services.attitude.simulation import coordinated_roll, fly, paper_plan
from shared.filters.angles import wrap_deg_180
from shared.filters.covariance import is_cholesky_factorable

D2R = math.pi / 180.0
EPS0 = math.asin(0.05)
P0 = (49937.46, 5000.0, 86494.22)
V220 = (-153.2089, 0.0, -128.5575)


def assert_each(actual: list[float], expected: list[float], tols: list[float]) -> None:
    """|actual_i - expected_i| <= tol_i for every i (one unit of the digest's last printed digit)."""
    assert len(actual) == len(expected) == len(tols)
    for a, e, t in zip(actual, expected, tols, strict=True):
        assert abs(a - e) <= t, (actual, expected, tols)


def state(p: tuple[float, float, float], v: tuple[float, float, float], a: tuple[float, float, float]) -> list[float]:
    return [p[0], v[0], a[0], p[1], v[1], a[1], p[2], v[2], a[2]]


def los_deg(p: tuple[float, float, float], psi: float, theta: float, gamma: float, los_x: str = "radar_to_target"):
    """LOS and aspect angles (deg) of a given attitude (deg) at a position, LOS direction from the position."""
    beta = math.atan2(p[2], p[0])
    eps = math.atan2(p[1], math.hypot(p[0], p[2]))
    out = attitude_angles(psi * D2R, theta * D2R, gamma * D2R, beta, eps, los_x)
    return [math.degrees(float(v)) for v in out]


def coordinated_state(p, speed, psi_deg, theta_deg, gamma_deg, g=9.81):
    """A 9-state whose eq. (4) attitude is (psi, theta, gamma): level-pitch-rate coordinated turn.

    With theta_dot = 0: n cos(gamma) = cos(theta) and psi_dot = n g sin(gamma) / (V cos(theta)).
    """
    psi, th, ga = psi_deg * D2R, theta_deg * D2R, gamma_deg * D2R
    n = math.cos(th) / math.cos(ga)
    psi_dot = n * g * math.sin(ga) / (speed * math.cos(th))
    i = np.array([math.cos(th) * math.cos(psi), math.sin(th), math.cos(th) * math.sin(psi)])
    di_dpsi = np.array([-math.cos(th) * math.sin(psi), 0.0, math.cos(th) * math.cos(psi)])
    v = speed * i
    a = speed * psi_dot * di_dpsi
    return state(p, tuple(v), tuple(a))


# ----------------------------------------------------------------------------------------------------- U1-U3
def test_u1_conversion_eq1() -> None:
    z = spherical_to_cartesian(100_000.0, 60.0 * D2R, EPS0)
    assert z == pytest.approx([49_937.461, 5_000.000, 86_494.219], abs=1e-3)
    assert math.degrees(EPS0) == pytest.approx(2.86598, abs=1e-5)


def test_u2_covariance_conversion_9s15() -> None:
    _, r = convert_plot(100_000.0, 60.0 * D2R, EPS0, 225.0, 0.35 * D2R, 0.3 * D2R)
    assert np.array_equal(r, r.T)
    principal = np.sqrt(np.linalg.eigvalsh(r))
    assert principal == pytest.approx([225.0, 523.6, 610.1], abs=0.1)
    assert np.sqrt(np.diag(r)) == pytest.approx([540.34, 523.06, 362.55], abs=0.01)
    assert r[0, 2] == pytest.approx(-139_014.0, abs=1.0)


def test_u3_jacobian_matches_central_differences() -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        r, b, e = rng.uniform(1e3, 3e5), rng.uniform(-math.pi, math.pi), rng.uniform(-1.4, 1.4)
        h = conversion_jacobian(r, b, e)
        steps = (1e-3, 1e-7, 1e-7)
        fd = np.empty((3, 3))
        for k, d in enumerate(steps):
            up = [r, b, e]
            dn = [r, b, e]
            up[k] += d
            dn[k] -= d
            fd[:, k] = (spherical_to_cartesian(*up) - spherical_to_cartesian(*dn)) / (2 * d)
        scale = np.abs(fd).max(axis=0)
        assert np.all(np.abs(h - fd) <= 1e-6 * scale)


# ----------------------------------------------------------------------------------------------------- U4 FSF
@pytest.mark.parametrize("times", [(0.0, 5.0, 10.0), (3.0, 4.2, 11.7), (100.0, 101.5, 108.0)])
def test_u4_fsf_recovers_quadratic_trajectory_exactly(times: tuple[float, float, float]) -> None:
    p0 = np.array([5e4, 3e3, -2e4])
    v0 = np.array([-150.0, 12.0, 80.0])
    a0 = np.array([2.5, -0.7, 1.3])
    t_ref = times[-1]
    zs = np.array([p0 + v0 * t + 0.5 * a0 * t * t for t in times])
    rng = np.random.default_rng(0)
    rs = []
    for _ in times:
        m = rng.normal(size=(3, 3)) * 300.0
        rs.append(m @ m.T + np.eye(3) * 1e3)
    alpha, _ = fsf_estimate([t - t_ref for t in times], zs, np.array(rs))
    truth = state(tuple(p0 + v0 * t_ref + 0.5 * a0 * t_ref**2), tuple(v0 + a0 * t_ref), tuple(a0))  # at the latest time
    assert alpha == pytest.approx(truth, rel=1e-9, abs=1e-9 * 1e5)
    raw = quadratic_state([t - t_ref for t in times], zs.tolist())
    assert raw == pytest.approx(truth, rel=1e-9, abs=1e-9 * 1e5)


def test_u4_fsf_weighted_least_squares_with_more_plots_is_exact_on_quadratic_data() -> None:
    times = np.array([0.0, 4.0, 9.0, 15.0, 20.0])
    p0, v0, a0 = np.array([1e4, 2e3, 3e4]), np.array([100.0, -5.0, 50.0]), np.array([1.0, 0.2, -0.5])
    zs = np.array([p0 + v0 * t + 0.5 * a0 * t * t for t in times])
    rs = np.array([np.diag([400.0, 900.0, 100.0]) * (1 + k) for k in range(5)])
    alpha, cov = fsf_estimate(times - times[-1], zs, rs)
    truth = state(tuple(zs[-1]), tuple(v0 + a0 * times[-1]), tuple(a0))
    assert alpha == pytest.approx(truth, rel=1e-9, abs=1e-6)
    assert np.array_equal(cov, cov.T) and is_cholesky_factorable(cov)


def test_u4_fsf_covariance_closed_form_uniform_t() -> None:
    t = 5.0
    rng = np.random.default_rng(1)
    m = rng.normal(size=(3, 3)) * 500.0
    r = m @ m.T + np.eye(3)
    _, cov = fsf_estimate([-2 * t, -t, 0.0], np.zeros((3, 3)), np.array([r, r, r]))
    p_idx, v_idx, a_idx = [0, 3, 6], [1, 4, 7], [2, 5, 8]
    blk = lambda i, j: cov[np.ix_(i, j)]  # noqa: E731
    assert blk(v_idx, v_idx) == pytest.approx(6.5 * r / t**2, rel=1e-9)
    assert blk(a_idx, a_idx) == pytest.approx(6.0 * r / t**4, rel=1e-9)
    assert blk(p_idx, v_idx) == pytest.approx(1.5 * r / t, rel=1e-9)
    assert blk(p_idx, a_idx) == pytest.approx(r / t**2, rel=1e-9)
    assert blk(v_idx, a_idx) == pytest.approx(6.0 * r / t**3, rel=1e-9)
    assert blk(p_idx, p_idx) == pytest.approx(r, rel=1e-9)


def test_fsf_design_rows() -> None:
    h = fsf_design([-10.0, -5.0, 0.0])
    assert h.shape == (9, 9)
    assert h[3 * 0 + 1, 3:6].tolist() == [1.0, -10.0, 50.0]  # plot 1, axis y
    assert h[3 * 2 + 2, 6:9].tolist() == [1.0, 0.0, 0.0]  # plot 3, axis z


# ----------------------------------------------------------------------------------------------------- U5 models
def test_u5_transition_and_process_noise() -> None:
    assert transition_axis(5.0).tolist() == [[1.0, 5.0, 12.5], [0.0, 1.0, 5.0], [0.0, 0.0, 1.0]]
    m = process_noise(5.0, (0.03**2,) * 3)
    expected = [[0.39063, 0.23438, 0.09375], [0.23438, 0.14063, 0.05625], [0.09375, 0.05625, 0.0225]]
    for c in range(3):
        assert m[3 * c : 3 * c + 3, 3 * c : 3 * c + 3] == pytest.approx(np.array(expected), abs=1e-5)
    # axis-blocked structure, no cross-axis terms, M = S^T D S
    s = jerk_input(5.0)
    assert m == pytest.approx(s.T @ np.diag([9e-4] * 3) @ s, rel=1e-12)
    assert np.count_nonzero(m) == 27
    b = transition(5.0)
    assert b[3:6, 3:6].tolist() == transition_axis(5.0).tolist() and np.count_nonzero(b) == 18
    assert H_POS @ np.arange(9.0) == pytest.approx([0.0, 3.0, 6.0])


def test_process_noise_differs_from_filterpy_white_noise_helper() -> None:
    # the digest warns: Q_discrete_white_noise is the acceleration-increment model, not the paper's jerk model
    from filterpy.common import Q_discrete_white_noise

    q = Q_discrete_white_noise(dim=3, dt=5.0, var=9e-4)
    assert not np.allclose(q, process_noise(5.0, (9e-4,) * 3)[:3, :3])


# ----------------------------------------------------------------------------------------------------- U6-U8 eq. 4
def test_u6_heading_and_pitch() -> None:
    vals, _, _ = angle_block(state(P0, V220, (0.0, 0.0, 0.0)), AngleConventions(), None, jacobian=False)
    assert math.degrees(vals[0]) == pytest.approx(220.000, abs=1e-3)
    assert math.degrees(vals[1]) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize(("g", "expected"), [(9.82, 30.00), (9.81, 30.03)])
def test_u7_level_coordinated_turn(g: float, expected: float) -> None:
    conv = AngleConventions(g_mps2=g)
    vals, _, kin = angle_block(state(P0, V220, (3.6443, 0.0, -4.3431)), conv, None, jacobian=False)
    assert math.degrees(vals[2]) == pytest.approx(expected, abs=0.01)
    mirror, _, _ = angle_block(state(P0, V220, (-3.6443, 0.0, 4.3431)), conv, None, jacobian=False)
    if g == 9.82:
        assert math.degrees(mirror[2]) == pytest.approx(-30.00, abs=0.01)
    # the turn rate of the generating vector is g tan(30) / V with g = 9.82
    assert kin.psi_dot == pytest.approx(9.82 * math.tan(30 * D2R) / 200.0, rel=1e-4)


@pytest.mark.parametrize("g", [9.82, 9.81, 9.80665])
def test_u8_climbing_accelerating_pitch_turn(g: float) -> None:
    vals, _, kin = angle_block(
        state(P0, (-150.8813, 34.7296, -126.6044), (5.1446, 3.0389, -5.2975)), AngleConventions(g), None, False
    )
    deg = [math.degrees(v) for v in vals[:3]]
    tol = 0.01 if g == 9.82 else 0.05
    assert deg == pytest.approx([220.00, 10.00, 30.00], abs=tol)
    assert kin.load_factor == pytest.approx(1.5, abs=1e-3 if g == 9.82 else 2e-3)


def test_eq4_roll_equals_vector_form_and_physics() -> None:
    rng = np.random.default_rng(5)
    n_checked = 0
    for _ in range(500):
        v = rng.normal(size=3) * np.array([200, 60, 200])
        a = rng.normal(size=3) * 15.0
        vals, _, kin = angle_block(state((1e4, 1e3, 2e4), tuple(v), tuple(a)), AngleConventions(), None, False)
        if kin.load_factor <= 0.05:
            continue
        n_checked += 1
        assert vals[2] == pytest.approx(float(coordinated_roll(v[None, :], a[None, :], 9.81)[0]), abs=1e-9)
    assert n_checked > 300
    # level turn with bank gamma: psi_dot = g tan(gamma) / V returns gamma
    for bank in (-60.0, -10.0, 5.0, 45.0, 70.0):
        x = coordinated_state(P0, 180.0, 75.0, 0.0, bank)
        assert math.degrees(angle_block(x, AngleConventions(), None, False)[0][2]) == pytest.approx(bank, abs=1e-9)


def test_roll_mode_atan2_full_circle_for_negative_load() -> None:
    # push-over at -1 g normal force: arctan gives the principal value, atan2 the inverted attitude
    x = state(P0, (200.0, 0.0, 0.0), (0.0, -2 * 9.81, 0.0))
    g_arctan = angle_block(x, AngleConventions(roll_mode="arctan"), None, False)
    g_atan2 = angle_block(x, AngleConventions(roll_mode="atan2"), None, False)
    assert math.degrees(g_arctan[0][2]) == pytest.approx(0.0, abs=1e-9)
    assert abs(math.degrees(g_atan2[0][2])) == pytest.approx(180.0, abs=1e-9)
    assert g_arctan[2].load_factor == pytest.approx(-1.0) and g_atan2[2].load_factor == pytest.approx(1.0)


# ----------------------------------------------------------------------------------------------------- U9-U13
def test_u9_los_angles_level_flight() -> None:
    psi_l, th_l, g_l, g_e, q_az, q_el, q = los_deg(P0, 220.0, 0.0, 0.0)
    assert [psi_l, th_l, g_l, g_e] == pytest.approx([159.977, 2.693, 0.000, -0.981], abs=1e-3)
    assert_each([q_az, q_el, q], [20.00, -2.866, 20.20], [1e-2, 1e-3, 1e-2])


def test_u10_los_angles_bank_30() -> None:
    psi_l, th_l, g_l, g_e, q_az, q_el, _ = los_deg(P0, 220.0, 0.0, 30.0)
    assert [psi_l, th_l, g_l, g_e] == pytest.approx([159.977, 2.693, -28.276, 29.019], abs=1e-3)
    assert [q_az, q_el] == pytest.approx([18.87, 7.32], abs=1e-2)


def test_u11_los_angles_u8_attitude() -> None:
    psi_l, th_l, g_l, g_e, q_az, q_el, _ = los_deg((50_000.0, 5_000.0, 80_000.0), 220.0, 10.0, 30.0)
    assert [psi_l, th_l, g_l, g_e] == pytest.approx([161.815, 12.884, -31.487, 29.039], abs=1e-3)
    assert [q_az, q_el] == pytest.approx([22.08, -1.93], abs=1e-2)


@pytest.mark.parametrize(
    ("pos", "att", "expected"),
    [
        (P0, (220.0, 0.0, 30.0), [159.977, 2.693, -28.276, 29.019, 18.87, 7.32]),
        ((50_000.0, 5_000.0, 80_000.0), (220.0, 10.0, 30.0), [161.815, 12.884, -31.487, 29.039, 22.08, -1.93]),
    ],
)
def test_u10_u11_through_the_state_angle_block(pos, att, expected) -> None:
    """The same numbers from a 9-state whose eq. (4) attitude is the given one (whole §2.5 block)."""
    x = coordinated_state(pos, 200.0, *att)
    vals, _, _ = angle_block(x, AngleConventions(), None, jacobian=False)
    deg = [math.degrees(v) for v in vals]
    assert deg[:3] == pytest.approx(list(att), abs=1e-9)
    assert deg[3:7] == pytest.approx(expected[:4], abs=1e-3)
    assert deg[7:9] == pytest.approx(expected[4:], abs=1e-2)


def test_u12_truth_along_paper_scenario_at_200s() -> None:
    tr = fly(paper_plan(), [200.0])
    p = tr.p[0]
    r = float(np.linalg.norm(p))
    beta = math.degrees(math.atan2(p[2], p[0]))
    eps = math.degrees(math.asin(p[1] / r))
    assert_each([beta, eps, r / 1e3], [72.39, 4.483, 63.97], [1e-2, 1e-3, 1e-2])
    psi_l, th_l, _, g_e, q_az, _, _ = los_deg(tuple(p), math.degrees(tr.psi[0]), 0.0, 0.0)
    assert_each([psi_l, th_l, g_e], [147.53, 3.785, -2.405], [1e-2, 1e-3, 1e-3])
    assert q_az == pytest.approx(32.39, abs=1e-2)
    assert tr.p[0] == pytest.approx(np.array(P0) + 200.0 * np.array(V220), abs=0.05)


def test_u13_los_flip_switch() -> None:
    rng = np.random.default_rng(13)
    for _ in range(200):
        x = state(
            tuple(rng.uniform(-1e5, 1e5, 3) * [1, 0.05, 1] + [0, 3e3, 0]),
            tuple(rng.normal(size=3) * [200, 40, 200]),
            tuple(rng.normal(size=3) * 5),
        )
        a, _, _ = angle_block(x, AngleConventions(los_x="radar_to_target"), None, False)
        b, _, _ = angle_block(x, AngleConventions(los_x="target_to_radar"), None, False)
        d = [math.degrees(v) for v in a]
        e = [math.degrees(v) for v in b]
        assert float(wrap_deg_180(e[3] - d[3] - 180.0)) == pytest.approx(0.0, abs=1e-9)
        assert e[4] == pytest.approx(d[4], abs=1e-12)
        assert float(wrap_deg_180(e[5] + d[5])) == pytest.approx(0.0, abs=1e-9)
        assert e[6:] == pytest.approx(d[6:], abs=1e-12)  # Euler roll and aspect do not depend on the switch
    # the matrix itself: A' = diag(-1, 1, -1) A
    a_mat = los_matrix(1.0, 0.1)
    assert los_matrix(1.0, 0.1, "target_to_radar") == pytest.approx(np.diag([-1.0, 1.0, -1.0]) @ a_mat)


def test_u14_monte_carlo_size() -> None:
    assert pytest.approx(3073.28, abs=0.01) == 2 * 1.96**2 / 0.05**2
    assert monte_carlo_size(1.96, 0.05) == 3074


# ----------------------------------------------------------------------------------------------------- frames
def test_los_matrix_rows_and_body_axes_are_orthonormal() -> None:
    a = los_matrix(0.7, -0.2)
    assert a @ a.T == pytest.approx(np.eye(3), abs=1e-15)
    assert a[0] == pytest.approx(spherical_to_cartesian(1.0, 0.7, -0.2))
    i, j, k = body_axes(0.3, 0.2, -0.4)
    m = np.stack([i, j, k])
    assert m @ m.T == pytest.approx(np.eye(3), abs=1e-15)
    assert np.cross(i, j) == pytest.approx(k, abs=1e-15)


def test_scalar_and_vectorised_angle_blocks_agree() -> None:
    rng = np.random.default_rng(7)
    xs = np.column_stack(
        [
            rng.uniform(-1e5, 1e5, 100),
            rng.normal(size=100) * 200,
            rng.normal(size=100) * 5,
            rng.uniform(100, 1e4, 100),
            rng.normal(size=100) * 50,
            rng.normal(size=100) * 5,
            rng.uniform(-1e5, 1e5, 100),
            rng.normal(size=100) * 200,
            rng.normal(size=100) * 5,
        ]
    )
    for conv in (AngleConventions(), AngleConventions(9.82, "target_to_radar", "atan2")):
        for los_dir in (None, (1.1, 0.04)):
            batch, _ = angles_of_states(xs, conv, los_dir)
            for x, row in zip(xs, batch, strict=True):
                vals, _, _ = angle_block(x.tolist(), conv, los_dir, jacobian=False)
                assert vals == pytest.approx(row.tolist(), abs=1e-11)


def test_analytic_jacobian_matches_central_differences() -> None:
    """The core's exact Jacobian against §2.5's central differences (steps 1 m, 0.1 m/s, 0.01 m/s^2): the
    difference must shrink as h^2 (it is the finite-difference truncation error)."""
    rng = np.random.default_rng(11)
    for _ in range(40):
        x = np.array(
            [
                rng.uniform(2e4, 1e5),
                rng.normal() * 150 - 100,
                rng.normal() * 3,
                rng.uniform(1e3, 8e3),
                rng.normal() * 20,
                rng.normal() * 2,
                rng.uniform(2e4, 1e5),
                rng.normal() * 150 - 100,
                rng.normal() * 3,
            ]
        )
        for conv in (AngleConventions(), AngleConventions(los_x="target_to_radar", roll_mode="atan2")):
            for los_dir in (None, (0.9, 0.05)):
                _, jac, _ = angle_block(x.tolist(), conv, los_dir, jacobian=True)
                assert jac is not None
                errs = []
                for s in (1.0, 0.1):
                    fd = angle_jacobian(x, conv, (1.0 * s, 0.1 * s, 0.01 * s), los_dir)[1]
                    scale = np.abs(fd).max(axis=1, keepdims=True) + 1e-12
                    errs.append(float(np.max(np.abs(jac - fd) / scale)))
                assert errs[0] < 1e-2
                assert errs[1] < max(errs[0] * 0.05, 1e-7)


# ----------------------------------------------------------------------------------------------------- KF
def test_kalman_filter_matches_filterpy() -> None:
    """Same B, M, H, R and start: our predict/update (Joseph form) equals filterpy's KalmanFilter."""
    rng = np.random.default_rng(21)
    times = np.cumsum(rng.uniform(4.0, 6.0, 30))
    d_a = (0.03**2, 0.05**2, 0.02**2)
    x0, p0 = fsf_estimate(
        [-10.0, -5.0, 0.0],
        np.array([[5e4, 5e3, 8e4], [4.99e4, 5e3, 7.99e4], [4.98e4, 5e3, 7.98e4]]),
        np.array([np.diag([4e4, 9e4, 1e5])] * 3),
    )
    kf = KalmanFilter(dim_x=9, dim_z=3)
    kf.x = x0.copy()
    kf.P = p0.copy()
    kf.H = H_POS.copy()
    x, p = x0.copy(), p0.copy()
    t_prev = 0.0
    for t in times:
        dt = float(t - t_prev)
        t_prev = t
        z = rng.normal(size=3) * 300 + np.array([5e4, 5e3, 8e4])
        m = rng.normal(size=(3, 3)) * 200
        rz = m @ m.T + np.eye(3) * 100
        kf.predict(F=transition(dt), Q=process_noise(dt, d_a))
        kf.update(z, R=rz)
        x_pred, p_pred = predict(x, p, dt, d_a)
        x, p, nis = update(x_pred, p_pred, z, rz)
        assert x == pytest.approx(np.ravel(kf.x), rel=1e-9, abs=1e-6)
        assert p == pytest.approx(kf.P, rel=1e-7, abs=1e-9 * np.abs(kf.P).max())
        assert np.array_equal(p, p.T) and is_cholesky_factorable(p)
        s = kf.S
        nu = z - np.ravel(kf.x_prior)[[0, 3, 6]]
        assert nis == pytest.approx(float(nu @ np.linalg.solve(s, nu)), rel=1e-9)


def test_update_rejects_non_positive_definite_innovation() -> None:
    x = np.zeros(9)
    p = np.zeros((9, 9))
    with pytest.raises(np.linalg.LinAlgError):
        update(x, p, np.ones(3), -np.eye(3))
    assert not is_cholesky_factorable(-np.eye(9))
    assert not is_cholesky_factorable(np.full((9, 9), np.nan))


def test_config_presets_and_defaults() -> None:
    cfg = AttitudeConfig()
    assert cfg.measurement_sigmas() == MeasurementSigmas(sigma_r_m=225.0, sigma_az_deg=0.35, sigma_el_deg=0.3)
    assert AttitudeConfig(radar="Vostok3D").measurement_sigmas().sigma_r_m == 25.0
    assert AttitudeConfig(radar="19Zh6").measurement_sigmas().sigma_el_deg == 1.0
    assert AttitudeConfig(radar="19Zh6", sigma_el_deg=0.5).measurement_sigmas().sigma_el_deg == 0.5
    assert cfg.jerk_variances() == pytest.approx((9e-4, 9e-4, 9e-4))
    assert (cfg.fsf_n, cfg.g_mps2, cfg.los_x, cfg.los_dir_source, cfg.roll_mode) == (
        3,
        9.81,
        "radar_to_target",
        "filtered",
        "arctan",
    )
    assert (cfg.v_min_mps, cfg.valid_sigma_deg, cfg.min_updates_valid, cfg.max_gap_scans) == (10.0, 5.0, 10, 3)
    assert (cfg.idle_timeout_s, cfg.nis_gate, cfg.nis_reset_count, cfg.coast_output) == (60.0, 21.1, 3, False)
    with pytest.raises(ValueError):
        AttitudeConfig(radar=None, sigma_r_m=10.0)
    # the gate is the chi2(3) 99.99 % quantile
    from scipy.stats import chi2

    assert chi2.ppf(0.9999, 3) == pytest.approx(cfg.nis_gate, abs=0.01)
