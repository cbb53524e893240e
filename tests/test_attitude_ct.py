"""The nearly coordinated turn (CT) model of the IMM (services/attitude/models.py: ct_step, turn_rate; imm.augment).

References are independent of the implementation: the Singer and constant-acceleration closed forms (limits of
the CT model), central differences of the discrete map (its EKF Jacobian), the exact circle of a constant-rate
coordinated turn, and the moments of a Gaussian pushed through the implied turn rate (Monte Carlo).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import expm

from schemas import Header, RadarPlot
from services.attitude import imm
from services.attitude.config import AttitudeConfig, MotionModel
from services.attitude.core import AttitudeCore
from services.attitude.models import (
    OMEGA,
    block_diagonal,
    ct_horizontal,
    ct_predict,
    ct_step,
    ct_transitions,
    process_noise,
    singer_axis,
    transition,
    turn_rate,
)
from services.attitude.simulation import NS, FlightPlan, Segment, fly, measure, scan_times

CT = MotionModel(name="turn", kind="ct", sigma_accel_mps2=0.3, tau_s=5.0, sigma_turn_rate_dps=0.2, sojourn_s=60.0)


def state10(rng: np.random.Generator, omega: float) -> np.ndarray:
    """A plausible aircraft state [x Vx ax y Vy ay z Vz az omega] (m, m/s, m/s^2, rad/s)."""
    x = np.empty(10)
    x[[0, 3, 6]] = rng.uniform(-50e3, 50e3, 3)
    x[[1, 4, 7]] = rng.uniform(-250.0, 250.0, 3)
    x[[2, 5, 8]] = rng.uniform(-10.0, 10.0, 3)
    x[OMEGA] = omega
    return x


def random_spd(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.standard_normal((n, n)) * rng.uniform(0.1, 10.0, n)
    return a @ a.T + 1e-3 * np.eye(n)


def test_no_turn_is_the_singer_model_of_every_axis() -> None:
    """omega = 0 and no turn-rate noise: F and Q are blkdiag(singer_axis) (the straight model) and omega stays 0 with
    no variance: the same matrix exponentials, computed from other block matrices (to ~1e-10 relative)."""
    rng = np.random.default_rng(1)
    for dt in (0.5, 5.0, 17.5):
        x = state10(rng, 0.0)
        xp, f, q = ct_step(x, dt, 0.3, 8.0, 0.0)
        fs, qs = singer_axis(dt, 0.3, 8.0)
        assert f[:9, :9] == pytest.approx(block_diagonal(fs), rel=1e-9, abs=1e-12)
        assert q[:9, :9] == pytest.approx(block_diagonal(qs), rel=1e-9, abs=1e-12)
        assert xp[:9] == pytest.approx(block_diagonal(fs) @ x[:9], rel=1e-9, abs=1e-12)
        assert xp[OMEGA] == 0.0 and q[OMEGA, OMEGA] == 0.0 and f[OMEGA, OMEGA] == 1.0


def test_no_turn_and_no_mean_reversion_is_the_constant_acceleration_model() -> None:
    """omega -> 0 and tau -> infinity with the jerk density 2 sigma_a^2 / tau fixed: the paper's CA model of eq. (3)
    (B, and M = S^T D S for a jerk held over the step has the same density limit as white jerk only to first order,
    so Q is compared with white jerk's closed form q [dt^5/20, dt^4/8, dt^3/6; ...; dt])."""
    dt, qj, tau = 5.0, 0.09, 1e7
    x = state10(np.random.default_rng(2), 1e-12)
    _, f, q = ct_step(x, dt, math.sqrt(qj * tau / 2.0), tau, 0.0)
    assert f[:9, :9] == pytest.approx(transition(dt), rel=1e-5, abs=1e-5)
    white = qj * np.array(
        [[dt**5 / 20, dt**4 / 8, dt**3 / 6], [dt**4 / 8, dt**3 / 3, dt**2 / 2], [dt**3 / 6, dt**2 / 2, dt]]
    )
    assert q[:9, :9] == pytest.approx(block_diagonal(white), rel=1e-4, abs=1e-9)
    # and the paper's piecewise-constant jerk is the same model to within the discretisation (same diagonal of v, a)
    m = process_noise(dt, (qj / dt, qj / dt, qj / dt))
    assert q[2, 2] == pytest.approx(m[2, 2], rel=1e-4)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    omega=st.floats(-0.3, 0.3),
    dt=st.sampled_from([0.2, 1.0, 5.0, 12.0, 17.5]),
    tau=st.sampled_from([1.0, 5.0, 20.0, 1e4]),
)
def test_jacobian_is_the_derivative_of_the_discrete_map(seed: int, omega: float, dt: float, tau: float) -> None:
    """F of ct_step against central differences of its predicted state (steps scaled to each component, Richardson
    extrapolated: truncation O(h^4), so the steps can stay large against the rounding of 10^4 m positions)."""
    rng = np.random.default_rng(seed)
    x = state10(rng, omega)
    _, f, _ = ct_step(x, dt, 0.3, tau, 1e-5)

    def central(i: int, h: float) -> np.ndarray:
        d = np.zeros(10)
        d[i] = h
        return (ct_step(x + d, dt, 0.3, tau, 1e-5)[0] - ct_step(x - d, dt, 0.3, tau, 1e-5)[0]) / (2.0 * h)

    num = np.empty((10, 10))
    for i in range(10):
        h = 1e-3 if i == OMEGA else 1e-2 * max(1.0, abs(x[i]))
        num[:, i] = (4.0 * central(i, 0.5 * h) - central(i, h)) / 3.0
    scale = np.maximum(np.abs(f), 1.0)
    assert np.max(np.abs(num - f) / scale) < 1e-5


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    omega=st.floats(-1.0, 1.0),
    dt=st.sampled_from([0.01, 1.0, 5.0, 17.5, 60.0]),
    q_omega=st.sampled_from([0.0, 1e-6, 1e-3]),
)
def test_covariance_stays_symmetric_positive_semidefinite(seed: int, omega: float, dt: float, q_omega: float) -> None:
    """Q is symmetric PSD (it is an integral of G q G^T), so F P F^T + Q is for any SPD P."""
    rng = np.random.default_rng(seed)
    x = state10(rng, omega)
    _, f, q = ct_step(x, dt, 0.3, 5.0, q_omega)
    assert np.array_equal(q, q.T)
    assert np.linalg.eigvalsh(q).min() >= -1e-9 * max(1.0, np.abs(q).max())
    p = random_spd(rng, 10)
    pp = f @ p @ f.T + q
    pp = 0.5 * (pp + pp.T)
    assert np.linalg.eigvalsh(pp).min() > 0.0 and np.linalg.cholesky(pp) is not None


@settings(max_examples=60, deadline=None)
@given(
    omegas=st.lists(st.floats(-1.0, 1.0), min_size=1, max_size=6),
    dt=st.sampled_from([-5.0, 1e-3, 1.0, 5.0, 17.5, 60.0]),
    tau=st.sampled_from([0.5, 1.0, 5.0, 20.0, 1e3, 1e5]),
)
def test_closed_form_transition_is_the_matrix_exponential(omegas: list[float], dt: float, tau: float) -> None:
    """ct_transitions (Putzer's form of the complex 3x3 system, exact as omega -> 0 through sinc) against scipy's
    expm of ct_horizontal, including omega = 0 exactly, backwards steps and tau so long that it falls back."""
    om = np.array([0.0, *omegas])
    phi = ct_transitions(om, dt, tau)
    for i, w in enumerate(om):
        ref = expm(ct_horizontal(float(w), tau)[0] * dt)
        assert np.max(np.abs(phi[i] - ref)) <= 1e-9 * max(1.0, float(np.abs(ref).max()))


def test_a_coordinated_turn_is_predicted_exactly() -> None:
    """A level coordinated turn (a = omega x V, no deviation b): the mean moves on the exact circle, the acceleration
    turns with the velocity and stays omega x V, and omega is kept."""
    v, omega, dt = 150.0, 0.08, 5.0
    x = np.zeros(10)
    x[[0, 3, 6]] = (10e3, 3e3, -4e3)
    x[1], x[7] = v, 0.0  # flying north
    x[2], x[8] = 0.0, omega * v  # a = omega x V points east (omega > 0: heading grows)
    x[OMEGA] = omega
    xp, _, _ = ct_step(x, dt, 0.3, 5.0, 1e-6)
    r = v / omega
    ang = omega * dt
    assert xp[0] == pytest.approx(10e3 + r * math.sin(ang), abs=1e-6)
    assert xp[6] == pytest.approx(-4e3 + r * (1.0 - math.cos(ang)), abs=1e-6)
    assert (xp[1], xp[7]) == pytest.approx((v * math.cos(ang), v * math.sin(ang)), abs=1e-9)
    assert (xp[2], xp[8]) == pytest.approx((-omega * xp[7], omega * xp[1]), abs=1e-9)
    assert xp[3] == 3e3 and xp[OMEGA] == omega


def test_turn_rate_gradient_and_augmentation() -> None:
    """turn_rate's gradient against central differences; augment's first-order moments against a Monte-Carlo
    push of a small Gaussian; the variance cap keeps P PSD."""
    rng = np.random.default_rng(7)
    x = state10(rng, 0.0)
    w, g = turn_rate(x)
    assert w == pytest.approx((x[1] * x[8] - x[7] * x[2]) / (x[1] ** 2 + x[7] ** 2), rel=1e-14)
    for i in range(9):
        h = 1e-5 * max(1.0, abs(x[i]))
        d = np.zeros(10)
        d[i] = h
        assert g[i] == pytest.approx((turn_rate(x + d)[0] - turn_rate(x - d)[0]) / (2 * h), rel=1e-6, abs=1e-12)
    p = np.zeros((10, 10))
    p[:9, :9] = random_spd(rng, 9) * 1e-3
    xa, pa = x.copy(), p.copy()
    imm.augment(xa, pa)
    samples = rng.multivariate_normal(x[:9], p[:9, :9], 200_000)
    ws = (samples[:, 1] * samples[:, 8] - samples[:, 7] * samples[:, 2]) / (samples[:, 1] ** 2 + samples[:, 7] ** 2)
    assert xa[OMEGA] == pytest.approx(ws.mean(), abs=0.02 * ws.std())  # 4.5 standard errors of the mean
    assert pa[OMEGA, OMEGA] == pytest.approx(ws.var(), rel=0.02)
    cov = np.cov(np.column_stack([samples[:, [1, 2, 7, 8]], ws]).T)
    assert pa[OMEGA, [1, 2, 7, 8]] == pytest.approx(cov[4, :4], rel=0.03, abs=1e-9)
    assert np.linalg.eigvalsh(pa).min() > 0.0
    big = np.zeros((10, 10))
    big[:9, :9] = random_spd(rng, 9) * 1e4  # acceleration known to ~100 m/s^2: far beyond the cap
    imm.augment(x.copy(), big)
    assert big[OMEGA, OMEGA] == pytest.approx(imm.OMEGA_SIGMA_CAP**2 + imm.OMEGA_NUGGET, rel=1e-12)
    assert np.linalg.eigvalsh(big).min() > -1e-9 * np.abs(big).max()


def test_mixing_of_different_models_keeps_the_nine_state_marginal() -> None:
    """A bank with a CT model mixes 10-states; the 9-state part of every mixed estimate is what mixing the 9-state
    marginals gives (the turn rate never feeds back into a CA/Singer model's own state)."""
    rng = np.random.default_rng(11)
    models = (
        MotionModel(name="straight", kind="singer", sigma_accel_mps2=0.2, tau_s=20.0, sojourn_s=300.0),
        CT,
        MotionModel(name="onset", kind="ca", sigma_jerk_mps3=1.0, sojourn_s=20.0),
    )
    xs = np.stack([state10(rng, 0.05) for _ in range(3)])
    ps = np.stack([random_spd(rng, 10) for _ in range(3)])
    for j in (0, 2):
        imm.augment(xs[j], ps[j])
    state = imm.ImmState(xs, ps, np.array([0.6, 0.3, 0.1]))
    pi = imm.transition_probabilities(models, 5.0)
    _, x0, p0 = imm.mix(state, pi)
    _, x9, p9 = imm.mix(imm.ImmState(xs[:, :9].copy(), ps[:, :9, :9].copy(), state.mu), pi)
    assert x0[:, :9] == pytest.approx(x9, rel=1e-12) and p0[:, :9, :9] == pytest.approx(p9, rel=1e-10)
    for j in range(3):
        assert np.linalg.eigvalsh(p0[j]).min() > 0.0


def test_ct_model_learns_the_turn_rate_of_a_long_turn() -> None:
    """A 30 deg-bank level turn of 150 s at 150 m/s seen by an accurate radar: the CT model takes over in the turn
    and its turn rate converges to the truth (g tan(bank) / V = 3.8 deg/s); the straight model takes back after."""
    plan = FlightPlan(
        (30e3, 4e3, 20e3),
        150.0,
        90.0,
        0.0,
        (
            Segment(100.0),
            Segment(3.0, bank_deg=(0.0, 30.0)),
            Segment(150.0, bank_deg=(30.0, 30.0)),
            Segment(3.0, bank_deg=(30.0, 0.0)),
        ),
    )
    models = (
        MotionModel(name="straight", kind="singer", sigma_accel_mps2=0.2, tau_s=20.0, sojourn_s=300.0),
        CT,
        MotionModel(name="onset", kind="ca", sigma_jerk_mps3=1.0, sojourn_s=20.0),
    )
    times = scan_times(90, 5.0)
    cfg = AttitudeConfig(radar=None, sigma_r_m=20.0, sigma_az_deg=0.05, sigma_el_deg=0.05, imm_models=models)
    meas = measure(fly(plan, times), cfg.measurement_sigmas(), np.random.default_rng(1))[0].tolist()
    core = AttitudeCore(cfg)
    true_rate = math.degrees(9.81 * math.tan(math.radians(30.0)) / 150.0)
    rates, mu_ct, mu_end = [], [], None
    for k, (r, az, el) in enumerate(meas):
        core.step(
            RadarPlot(
                header=Header(stamp_ns=round(times[k] * NS)),
                site_id="r1",
                target_id="t",
                range_m=r,
                az_deg=az,
                el_deg=el,
            )
        )
        tr = core._tracks[("r1", "t")]
        if tr.imm is None:
            continue
        assert tr.imm.xs.shape == (3, 10)
        if 160.0 <= times[k] <= 250.0:
            rates.append(math.degrees(tr.imm.xs[1, OMEGA]))
            mu_ct.append(tr.imm.mu[1])
        mu_end = tr.imm.mu[0]
    assert np.mean(mu_ct) > 0.6
    assert abs(np.mean(rates) - true_rate) < 0.1 * true_rate
    assert mu_end is not None and mu_end > 0.5


def test_quadrature_prediction_is_the_ekf_for_a_known_turn_rate() -> None:
    """var(omega) = 0: the model is linear, and ct_predict gives the EKF's (exact) moments."""
    rng = np.random.default_rng(3)
    x = state10(rng, 0.07)
    p = random_spd(rng, 10)
    p[OMEGA, :] = 0.0
    p[:, OMEGA] = 0.0
    xq, pq = ct_predict(x, p, 5.0, 0.3, 5.0, 1e-5)
    xe, f, q = ct_step(x, 5.0, 0.3, 5.0, 1e-5)
    assert xq == pytest.approx(xe, rel=1e-9, abs=1e-9)
    assert pq == pytest.approx(f @ p @ f.T + q, rel=1e-8, abs=1e-8)


def test_quadrature_prediction_matches_monte_carlo_where_the_ekf_does_not() -> None:
    """A turn rate uncertain to 0.1 rad/s (6 deg/s, a turn entry): the moments of the exact map pushed through by
    Monte Carlo (20,000 draws) against ct_predict (Gauss-Hermite over omega) and the EKF. The quadrature's mean
    and position/velocity variances are within a few % of Monte Carlo; the EKF's heading-related spread is off by
    much more (it is why the CT model predicts by quadrature)."""
    rng = np.random.default_rng(5)
    x = np.array([20e3, 150.0, 0.0, 3e3, 0.0, 0.0, -10e3, 0.0, 12.0, 0.08])
    p = np.diag([200.0**2, 10.0**2, 1.0, 200.0**2, 5.0**2, 0.3**2, 200.0**2, 10.0**2, 1.0, 0.1**2])
    dt = 5.0
    xq, pq = ct_predict(x, p, dt, 0.3, 5.0, 0.0)
    xe, f, q = ct_step(x, dt, 0.3, 5.0, 0.0)
    pe = f @ p @ f.T + q
    draws = rng.multivariate_normal(x, p, 20_000)
    a_by_draw = np.array([ct_step(d, dt, 0.3, 5.0, 0.0)[0] for d in draws])
    mc_mean = a_by_draw.mean(axis=0)
    mc_cov = np.cov(a_by_draw.T) + q
    idx = [0, 1, 6, 7]  # horizontal position and velocity
    se = np.sqrt(np.diag(mc_cov)[idx] / 20_000)
    assert np.all(np.abs(xq[idx] - mc_mean[idx]) < 5.0 * se + 1e-6)
    assert np.diag(pq)[idx] == pytest.approx(np.diag(mc_cov)[idx], rel=0.05)
    # the EKF: a mean off by many standard errors or a variance off by > 20 % on the horizontal velocity
    ekf_bad = np.any(np.abs(xe[idx] - mc_mean[idx]) > 10.0 * se) or np.any(
        np.abs(np.diag(pe)[idx] / np.diag(mc_cov)[idx] - 1.0) > 0.2
    )
    assert ekf_bad
