"""The DR error model (services/rd_nav/drift.py) against independent computations (issue 16).

* the displacement error G e of constant speed-bias / heading / scale errors equals what an independent integration
  of the erroneous speed and heading gives (first order: the tolerance is the second-order term);
* at rest only the speed bias moves dead reckoning, by b per second along the heading;
* the EKF's discretised prediction reproduces the closed-form variance of the path integral of a Gauss-Markov
  velocity error, 2 sigma^2 tau^2 (x - 1 + e^-x), x = T / tau;
* the marginalised particle filter spreads exactly like the EKF when nothing is measured (Monte-Carlo tolerance);
* the coordinator's vectorised full-budget bound equals the per-point CRLB of the filters' geometry module.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.coordinator.budget import drms_full, schedule_fits
from services.rd_nav.dr import DeadReckoner
from services.rd_nav.drift import J90, DriftModel, gm_path_var
from services.rd_nav.ekf import EkfShadow
from services.rd_nav.geometry import crlb, jacobian_d, measurement_cov, motion_comp_cov, node_cov_term
from services.rd_nav.pf import ParticleFilter
from services.rd_nav.simulation import ProfilePath

MODEL = DriftModel(
    bias_mps=0.05,
    bias_tau_s=300.0,
    heading_rad=math.radians(2.0),
    heading_tau_s=300.0,
    scale=0.03,
    scale_tau_s=300.0,
    speed_white_mps=0.0,
    heading_white_rad=0.0,
    sample_period_s=1.0,
    floor_m=0.0,
    floor_path_m=15.0,
)


def _dr_track(speed: float, heading: list[float], dt: float, b: float = 0.0, dphi: float = 0.0, k: float = 0.0):
    """DR fed speed (1+k)V + b and heading + dphi at 1 Hz (the truth: V and heading), and the true track."""
    dr = DeadReckoner(buffer_s=10_000.0)
    x = np.zeros(2)
    for i, h in enumerate(heading):
        t = i * dt
        dr.add_velocity(t, (1.0 + k) * speed + b, 0.0, 0.0)
        dr.add_attitude(t, h + dphi)
        if i + 1 < len(heading):  # truth: the trapezoid of the two sample velocities, as DR integrates
            h2 = heading[i + 1]
            x = x + 0.5 * speed * dt * np.array([math.cos(h) + math.cos(h2), math.sin(h) + math.sin(h2)])
    return dr, x


@pytest.mark.parametrize(("b", "dphi", "k"), [(0.05, 0.0, 0.0), (0.0, math.radians(2.0), 0.0), (0.0, 0.0, 0.03)])
def test_displacement_error_is_g_times_the_errors(b: float, dphi: float, k: float) -> None:
    """A curved 60 s track: DR(with errors) - DR(without) = G e to second order (|e|^2 L)."""
    heading = [0.3 + 0.02 * i for i in range(61)]
    dr_err, _ = _dr_track(1.5, heading, 1.0, b, dphi, k)
    dr_true, _ = _dr_track(1.5, heading, 1.0)
    a, z = dr_true.at(0.0), dr_true.at(60.0)
    dX = np.array([z.x_m - a.x_m, z.y_m - a.y_m])
    U = np.array([z.un_s - a.un_s, z.ue_s - a.ue_s])
    ae, ze = dr_err.at(0.0), dr_err.at(60.0)
    err = np.array([ze.x_m - ae.x_m, ze.y_m - ae.y_m]) - dX
    step = MODEL.step(60.0, dX, U)
    pred = step.G @ np.array([b, dphi, k])
    second_order = (b + dphi + k) ** 2 * 90.0 + 1e-9  # |e|^2 x path: the neglected term
    assert np.linalg.norm(err - pred) <= second_order, (err, pred)
    assert np.linalg.norm(err) > 0.5  # the errors do move DR (2.9-3.1 m here)


def test_at_rest_only_the_speed_bias_moves_dead_reckoning() -> None:
    """Hovering (V = 0) for 100 s heading 30 deg: a bias b moves DR by b * 100 s along the heading; G's heading
    and scale columns are zero (they act through the displacement)."""
    dr = DeadReckoner(buffer_s=1000.0)
    h = math.radians(30.0)
    for i in range(101):
        dr.add_velocity(float(i), 0.05, 0.0, 0.0)
        dr.add_attitude(float(i), h)
    a, z = dr.at(0.0), dr.at(100.0)
    U = np.array([z.un_s - a.un_s, z.ue_s - a.ue_s])
    assert np.allclose(U, [100.0 * math.cos(h), 100.0 * math.sin(h)], rtol=0.0, atol=1e-9)
    step = MODEL.step(100.0, np.zeros(2), U)
    assert step.G[:, 1:] == pytest.approx(np.zeros((2, 2)))
    assert step.G @ np.array([0.05, 0.0, 0.0]) == pytest.approx([z.x_m - a.x_m, z.y_m - a.y_m], abs=1e-9)


def test_heading_column_is_the_displacement_turned_left() -> None:
    """Heading measured 1 rad too far clockwise (phi~ = phi + dphi): DR - true = dphi J dX, J = 90 deg to port."""
    dX = np.array([3.0, 4.0])
    assert J90 @ dX == pytest.approx([-4.0, 3.0])
    assert MODEL.step(10.0, dX, np.array([6.0, 8.0])).G[:, 1] == pytest.approx([-4.0, 3.0])


@given(st.floats(0.1, 5_000.0), st.floats(10.0, 3_000.0))
def test_gauss_markov_step_keeps_the_stationary_variance(dt: float, tau: float) -> None:
    """a^2 sigma^2 + w^2 = sigma^2 for every step length (the states stay stationary)."""
    m = DriftModel(0.05, tau, 0.03, tau, 0.02, tau, 0.0, 0.0, 1.0, 0.0, 15.0)
    s = m.step(dt, np.zeros(2), np.array([dt, 0.0]))
    assert np.allclose(s.a**2 * m.sigma**2 + s.w_sd**2, m.sigma**2, rtol=1e-12, atol=1e-15)
    assert np.all((s.a > 0.0) & (s.a <= 1.0))


@pytest.mark.parametrize("T", [60.0, 300.0, 900.0])
def test_ekf_prediction_matches_the_gauss_markov_path_variance(T: float) -> None:
    """Hovering heading north, bias only (sigma 0.05 m/s, tau 300 s), no fixes: after T the EKF's north variance is
    the closed form sigma^2 2 tau^2 (x - 1 + e^-x) to 1 % (its 10 s trapezoid steps)."""
    m = DriftModel(0.05, 300.0, 0.0, 300.0, 0.0, 300.0, 0.0, 0.0, 1.0, 0.0, 15.0)
    ekf = EkfShadow()
    ekf.init(np.zeros(2), np.zeros((2, 2)), m.prior_cov())
    for _ in range(int(T / 10.0)):
        ekf.predict_drift(np.zeros(2), m.step(10.0, np.zeros(2), np.array([10.0, 0.0])))
    want = 0.05**2 * gm_path_var(T, 300.0)
    assert ekf.P[0, 0] == pytest.approx(want, rel=0.01)
    assert ekf.P[1, 1] == pytest.approx(0.0, abs=1e-12)


def test_marginalised_pf_spreads_like_the_ekf() -> None:
    """Moving on a circle for 600 s with every error state, no fixes: the particle covariance equals the EKF's.
    4,000 particles: a variance's relative standard error is sqrt(2 / N) = 2.2 %; the tolerance is 4 of them."""
    m = DriftModel(0.05, 300.0, math.radians(2.0), 300.0, 0.03, 300.0, 0.02, math.radians(0.5), 1.0, 0.1, 15.0)
    pf = ParticleFilter(4000, np.random.default_rng(3))
    pf.init_gaussian(np.zeros(2), 0.01 * np.eye(2), m.prior_cov())
    ekf = EkfShadow()
    ekf.init(np.zeros(2), 0.01 * np.eye(2), m.prior_cov())
    for i in range(60):
        h = 0.1 * i
        dX = 15.0 * np.array([math.cos(h), math.sin(h)])
        st_ = m.step(10.0, dX, dX / 1.5)
        pf.predict_drift(dX, st_)
        ekf.predict_drift(dX, st_)
    mean, cov = pf.estimate()
    assert mean == pytest.approx(ekf.x, abs=4.0 * math.sqrt(float(np.trace(ekf.P)) / 4000))
    rel = np.linalg.eigvalsh(np.linalg.solve(ekf.P, cov))
    assert np.all(np.abs(rel - 1.0) < 4.0 * math.sqrt(2.0 / 4000)), rel


@settings(max_examples=40, deadline=None)
@given(
    st.tuples(st.floats(-6000.0, 6000.0), st.floats(-6000.0, 6000.0)),
    st.integers(0, 5),
    st.floats(0.0, 0.5e-3),
    st.floats(0.0, 1.0),
    st.floats(0.0, 1.0),
    st.floats(0.0, 0.1),
)
def test_coordinator_bound_equals_the_filters_crlb(
    p: tuple[float, float], leader: int, sigma_f: float, sigma_c: float, sigma_node: float, sigma_v: float
) -> None:
    """budget.drms_full (vectorised over sets and points) = trace of (H^T R^-1 H)^-1 with geometry.py's R builders."""
    nodes = np.array([[2481.935, 1500.0, 100.0], [0.0, 0.0, 100.0], [0.0, 3000.0, 100.0], [-1500.0, 1500.0, 100.0]])
    order = [leader % 4, *(j for j in range(4) if j != leader % 4)][:3]
    tau = np.array([0.5, 3.5])
    got = drms_full(
        nodes,
        np.array([[p[0], p[1], 80.0]]),
        np.array([order[0]]),
        np.array([order[1:]]),
        tau,
        1500.0,
        0.2e-3,
        sigma_f,
        sigma_c,
        sigma_node,
        sigma_v,
    )[0, 0]
    L, F = nodes[order[0]], nodes[order[1:]]
    pp = np.array(p)
    zj, delta = np.full(2, 80.0), np.zeros((2, 2))
    H = jacobian_d(pp.reshape(1, 2), L, F, delta, 80.0, zj)[0]
    q = np.array([*p, 80.0])
    s = np.linalg.norm(F - L, axis=1) + np.linalg.norm(F - q, axis=1) - np.linalg.norm(q - L)
    extra = node_cov_term(pp, 80.0, zj, delta, L, F, sigma_node, np.full(2, sigma_node))
    extra = extra + motion_comp_cov(pp, zj, delta, F, tau + s / 1500.0, sigma_v)
    R = measurement_cov(s, 1500.0, 0.2e-3, sigma_f, sigma_c, extra)
    try:
        want = math.sqrt(float(np.trace(crlb(H, R))))
    except np.linalg.LinAlgError:
        want = math.inf
    if not math.isfinite(want) or want > 1e4:  # near-singular: both must say "useless"
        assert got > 1e3 or not math.isfinite(got)
    else:
        assert got == pytest.approx(want, rel=1e-6)


def test_schedule_check_is_the_digests_non_overlap_condition() -> None:
    """§4.9: REF layout, tau 0.5/3.5 s, T_pkt 0.4 s, g 0.1 s. The last reply ends before the next leader packet at
    every receiver iff T_c >= tau_3 + s_3/c + T_pkt + g with s_3 <= 2 r_13: 7.87 s at most, reached beyond the
    leader on the A3-A1 line. 1.5 km beyond the apex s_3 = 5654 m: 7.77 s; T_c = 10 s fits, 7.5 s does not."""
    nodes = np.array([[2481.935, 1500.0, 100.0], [0.0, 0.0, 100.0], [0.0, 3000.0, 100.0]])
    beyond = np.array([[4000.0, 1500.0, 100.0]])
    args = (nodes, beyond, np.array([0]), np.array([[1, 2]]), np.array([0.5, 3.5]), 1500.0)
    assert schedule_fits(*args, 10.0, 0.4, 0.1)[0]
    assert schedule_fits(*args, 7.8, 0.4, 0.1)[0]
    assert not schedule_fits(*args, 7.7, 0.4, 0.1)[0]


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-5e3, 5e3), st.floats(-5e3, 5e3)), min_size=2, max_size=6),
    st.data(),
)
def test_profile_path_hovers_and_keeps_its_speeds(wps: list[tuple[float, float]], data: st.DataObject) -> None:
    """ProfilePath: on a leg the speed is the leg's; while holding the speed is 0 and the position the waypoint;
    the position is continuous (moves at most speed * dt between samples); it never leaves the waypoints' hull box."""
    n = len(wps)
    speeds = data.draw(st.lists(st.floats(0.1, 3.0), min_size=n - 1, max_size=n - 1))
    holds = data.draw(st.lists(st.floats(0.0, 300.0), min_size=n, max_size=n))
    if all(math.dist(a, b) < 1e-6 for a, b in itertools.pairwise(wps)):
        return
    repeat = data.draw(st.booleans())
    if repeat:
        wps = [*wps, wps[0]]
        speeds = [*speeds, speeds[0]]
        holds = [*holds, 0.0]
    path = ProfilePath(wps, 0.0, speeds, holds, repeat=repeat)
    xs = np.array([w[0] for w in wps])
    ys = np.array([w[1] for w in wps])
    prev = None
    vmax = max(speeds)
    for t in np.linspace(0.0, 1.2 * (path.period or 1.0), 400):
        x, y, h, v = path.state(float(t))
        assert xs.min() - 1e-6 <= x <= xs.max() + 1e-6 and ys.min() - 1e-6 <= y <= ys.max() + 1e-6
        assert v == 0.0 or any(abs(v - s) < 1e-12 for s in speeds)
        assert math.isfinite(h)
        if prev is not None:
            dt = float(t) - prev[0]
            assert math.dist((x, y), prev[1:]) <= vmax * dt + 1e-6
        prev = (float(t), x, y)
