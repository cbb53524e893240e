"""The interacting-multiple-model filter of the default preset (services/attitude/imm.py), unit by unit.

References are independent of the implementation: the Markov chain's closed form, the mixture moments written as
E[x x^T] - E[x] E[x]^T, the single Kalman filter of eq. (3) (filter.predict / filter.update), the closed-form
white-jerk process noise and the stationary variance of a first-order Markov acceleration.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas import Header, RadarPlot
from services.attitude import imm
from services.attitude.config import CA_MODELS, MANOEUVRE_MODELS, AttitudeConfig, MotionModel
from services.attitude.core import AttitudeCore
from services.attitude.filter import predict, update
from services.attitude.geometry import convert_plot
from services.attitude.initiation import fsf_estimate
from services.attitude.models import process_noise, singer_axis, transition
from services.attitude.simulation import NS, fly, measure, paper_plan, scan_times

CA = MotionModel(name="ca", kind="ca", sigma_jerk_mps3=0.03, sojourn_s=100.0)


def random_spd(rng: np.random.Generator, n: int = 9) -> np.ndarray:
    a = rng.standard_normal((n, n))
    return a @ a.T + n * np.eye(n)


def test_transition_probabilities_are_the_markov_chain_over_dt() -> None:
    for dt in (0.5, 5.0, 37.0):
        pi = imm.transition_probabilities(CA_MODELS, dt)
        assert pi.sum(axis=1) == pytest.approx(np.ones(3), abs=1e-15)
        for i, m in enumerate(CA_MODELS):
            assert pi[i, i] == pytest.approx(math.exp(-dt / m.sojourn_s), rel=1e-14)
            others = [pi[i, j] for j in range(3) if j != i]
            assert others[0] == pytest.approx(others[1]) and others[0] > 0.0
    assert imm.transition_probabilities((CA,), 5.0).tolist() == [[1.0]]


def test_transition_probabilities_follow_exits_to() -> None:
    """The default bank: the turn model switches only to the models its exits_to names (a turn ends in straight
    flight or a new onset, not in another model), equally; the other rows share equally among all others."""
    names = [m.name for m in MANOEUVRE_MODELS]
    for dt in (1.0, 5.0):
        pi = imm.transition_probabilities(MANOEUVRE_MODELS, dt)
        assert pi.sum(axis=1) == pytest.approx(np.ones(len(names)), abs=1e-15)
        for i, m in enumerate(MANOEUVRE_MODELS):
            assert pi[i, i] == pytest.approx(math.exp(-dt / m.sojourn_s), rel=1e-14)
            targets = [j for j in range(len(names)) if j != i and (m.exits_to is None or names[j] in m.exits_to)]
            others = [j for j in range(len(names)) if j != i and j not in targets]
            assert pi[i, targets] == pytest.approx(np.full(len(targets), (1.0 - pi[i, i]) / len(targets)), rel=1e-14)
            assert all(pi[i, j] == 0.0 for j in others)
    with pytest.raises(ValueError, match="exits_to"):
        AttitudeConfig(
            imm_models=(CA, MotionModel(name="x", kind="ca", sigma_jerk_mps3=1.0, sojourn_s=9.0, exits_to=("nope",)))
        )


def test_mixing_probabilities_sum_to_one_and_mixing_is_convex() -> None:
    rng = np.random.default_rng(4)
    xs = rng.standard_normal((3, 9)) * 100.0
    ps = np.stack([random_spd(rng) for _ in range(3)])
    state = imm.ImmState(xs, ps, np.array([0.7, 0.2, 0.1]))
    pi = imm.transition_probabilities(MANOEUVRE_MODELS, 5.0)
    c, x0, p0 = imm.mix(state, pi)
    assert c == pytest.approx(state.mu @ pi, rel=1e-14) and c.sum() == pytest.approx(1.0, abs=1e-15)
    # mu_i|j = pi_ij mu_i / c_j: every column sums to 1, so the mixed means are convex combinations
    w = state.mu[:, None] * pi / c[None, :]
    assert w.sum(axis=0) == pytest.approx(np.ones(3), abs=1e-15)
    assert x0 == pytest.approx(w.T @ xs, rel=1e-12)
    for j in range(3):  # covariance of the mixture of the component Gaussians with weights mu_i|j
        second = sum(w[i, j] * (ps[i] + np.outer(xs[i], xs[i])) for i in range(3))
        assert p0[j] == pytest.approx(second - np.outer(x0[j], x0[j]), rel=1e-8, abs=1e-6)
    # equal components: mixing changes nothing
    same = imm.ImmState(np.repeat(xs[:1], 3, axis=0), np.repeat(ps[:1], 3, axis=0), state.mu)
    _, x1, p1 = imm.mix(same, pi)
    assert np.allclose(x1, xs[0], rtol=0, atol=1e-9) and np.allclose(p1, ps[0], rtol=1e-12, atol=1e-9)


def test_combine_is_the_moment_matched_mixture() -> None:
    rng = np.random.default_rng(5)
    xs = rng.standard_normal((3, 9)) * 10.0
    ps = np.stack([random_spd(rng) for _ in range(3)])
    mu = np.array([0.5, 0.3, 0.2])
    x, p = imm.combine(xs, ps, mu)
    second = sum(mu[j] * (ps[j] + np.outer(xs[j], xs[j])) for j in range(3))
    assert x == pytest.approx(mu @ xs, rel=1e-13)
    assert p == pytest.approx(second - np.outer(x, x), rel=1e-9, abs=1e-9)
    assert np.array_equal(p, p.T) and np.linalg.eigvalsh(p).min() > 0.0


def _plots(n: int, seed: int) -> tuple[list[float], list[tuple[np.ndarray, np.ndarray]]]:
    cfg = AttitudeConfig()
    times = scan_times(n, 5.0).tolist()
    meas = measure(fly(paper_plan(), times), cfg.measurement_sigmas(), np.random.default_rng(seed))[0]
    sig = cfg.measurement_sigmas()
    out = []
    for r, az, el in meas.tolist():
        out.append(
            convert_plot(
                r,
                math.radians(az),
                math.radians(el),
                sig.sigma_r_m,
                *map(math.radians, (sig.sigma_az_deg, sig.sigma_el_deg)),
            )
        )
    return times, out


@pytest.mark.parametrize("n_models", [1, 3])
def test_imm_of_equal_models_is_the_kalman_filter_of_eq3(n_models: int) -> None:
    """M equal models: the mixing and the model probabilities cannot change anything, so every cycle must give
    the single Kalman filter's alpha and P (filter.predict / filter.update, eq. 3) -- computed independently."""
    times, plots = _plots(40, seed=9)
    x, p = fsf_estimate(
        np.array(times[:3]) - times[2], np.stack([z for z, _ in plots[:3]]), np.stack([r for _, r in plots[:3]])
    )
    models = (CA,) * n_models
    state = imm.ImmState.start(x, p, tuple([1.0 / n_models] * n_models))
    kx, kp = x, p
    for k in range(3, 40):
        dt = times[k] - times[k - 1]
        z, rz = plots[k]
        res = imm.step(state, models, dt, z, rz)
        xp, pp = predict(kx, kp, dt, (0.03**2,) * 3)
        kx, kp, nis = update(xp, pp, z, rz)
        assert res.x == pytest.approx(kx, rel=1e-9, abs=1e-9)
        assert res.p == pytest.approx(kp, rel=1e-9, abs=1e-12)
        assert res.nis == pytest.approx(nis, rel=1e-9)
        assert res.state.mu == pytest.approx(np.full(n_models, 1.0 / n_models), abs=1e-12)
        state = res.state


def test_core_with_equal_models_gives_the_paper_filter() -> None:
    """Through the whole core: the IMM of three copies of the paper's model (same gate, same status rules) gives
    the paper preset's estimates."""
    truth = fly(paper_plan(), scan_times(60, 5.0))
    meas = measure(truth, AttitudeConfig().measurement_sigmas(), np.random.default_rng(3))[0].tolist()
    plots = [
        RadarPlot(
            header=Header(stamp_ns=round(5.0 * k * NS)), site_id="r1", target_id="a", range_m=r, az_deg=az, el_deg=el
        )
        for k, (r, az, el) in enumerate(meas)
    ]
    paper = AttitudeCore(AttitudeConfig(preset="paper"))
    same = AttitudeCore(
        AttitudeConfig(preset="paper", motion="imm", imm_models=(CA, CA, CA), imm_initial_probabilities=(0.2, 0.3, 0.5))
    )
    mu = np.array([0.2, 0.3, 0.5])  # equal likelihoods: mu only follows the Markov chain, mu <- mu pi
    pi = imm.transition_probabilities((CA, CA, CA), 5.0)
    for pl in plots:
        a, b = paper.step(pl)[0], same.step(pl)[0]
        assert a.status == b.status and a.flags == b.flags
        if a.estimate is not None:
            assert b.estimate.mean == pytest.approx(a.estimate.mean, rel=1e-9, abs=1e-8)
            for f in ("psi_los_deg", "theta_los_deg", "gamma_los_deg", "sigma_psi_los_deg", "gamma_deg"):
                va, vb = getattr(a, f), getattr(b, f)
                assert (va is None and vb is None) or vb == pytest.approx(va, rel=1e-7, abs=1e-7), f
            if b.n_updates > 3:
                mu = mu @ pi
            assert b.model_probabilities == pytest.approx(mu.tolist(), abs=1e-12)


def test_singer_model_limits() -> None:
    """Singer model (Van Loan): as tau -> infinity with q = 2 sigma^2 / tau fixed it is the constant-acceleration
    model driven by white jerk of density q, whose Q has the closed form q [dt^5/20, dt^4/8, dt^3/6; ...; dt]; over
    a long step the acceleration variance reaches the stationary sigma_a^2 and its transition forgets a."""
    dt, q = 5.0, 0.01
    tau = 1e7
    f, qm = singer_axis(dt, math.sqrt(q * tau / 2.0), tau)
    white = q * np.array(
        [[dt**5 / 20, dt**4 / 8, dt**3 / 6], [dt**4 / 8, dt**3 / 3, dt**2 / 2], [dt**3 / 6, dt**2 / 2, dt]]
    )
    assert f == pytest.approx(transition(dt)[:3, :3], rel=1e-5, abs=1e-5)
    assert qm == pytest.approx(white, rel=1e-4)
    f2, q2 = singer_axis(500.0, 0.2, 20.0)  # acceleration variance from a known start: sigma^2 (1 - e^(-2 dt / tau))
    assert q2[2, 2] == pytest.approx(0.04 * (1.0 - math.exp(-50.0)), rel=1e-9)
    assert f2[2, 2] == pytest.approx(math.exp(-25.0), rel=1e-6)
    f3, q3 = singer_axis(15.0, 0.2, 20.0)  # chained sub-steps = one exponential where both are exact
    f4, q4 = singer_axis(7.5, 0.2, 20.0)
    assert f3 == pytest.approx(f4 @ f4, rel=1e-12) and q3 == pytest.approx(f4 @ q4 @ f4.T + q4, rel=1e-9)
    assert np.linalg.eigvalsh(q2).min() > -1e-9


@settings(max_examples=60, deadline=None)
@given(
    dt=st.floats(0.1, 20.0),
    sigma_j=st.floats(0.01, 5.0),
    k=st.floats(0.0, 10.0),
)
def test_vertical_jerk_factor_scales_only_the_vertical_block(dt: float, sigma_j: float, k: float) -> None:
    """A ca model's Q with vertical_jerk_factor k is M = S^T D S with D = diag(s^2, (k s)^2, s^2) over E [north, up,
    east]: a jerk held constant over the step enters each axis as g = [dt^3/6, dt^2/2, dt], so Q = blkdiag(D_c g g^T)
    in the axis-blocked state; k touches only the y (up) block, and k = 1 leaves Q bit-identical."""
    iso = MotionModel(name="onset", kind="ca", sigma_jerk_mps3=sigma_j, sojourn_s=20.0)
    aniso = MotionModel(name="onset", kind="ca", sigma_jerk_mps3=sigma_j, vertical_jerk_factor=k, sojourn_s=20.0)
    g = np.array([dt**3 / 6.0, dt**2 / 2.0, dt])
    d = [sigma_j**2, (k * sigma_j) ** 2, sigma_j**2]
    closed = np.zeros((9, 9))
    for c in range(3):
        closed[3 * c : 3 * c + 3, 3 * c : 3 * c + 3] = d[c] * np.outer(g, g)
    f1, q1 = imm.model_matrices(iso, dt)
    fk, qk = imm.model_matrices(aniso, dt)
    assert np.array_equal(fk, f1)
    scale = max(1.0, float(np.abs(closed).max()))
    assert np.abs(qk - closed).max() <= 1e-12 * scale
    up = np.zeros(9, dtype=bool)
    up[3:6] = True
    assert np.array_equal(qk[~up][:, ~up], q1[~up][:, ~up])  # the horizontal blocks: the same bits
    assert not qk[up][:, ~up].any() and not qk[~up][:, up].any()  # no cross-axis terms
    one = MotionModel(name="onset", kind="ca", sigma_jerk_mps3=sigma_j, vertical_jerk_factor=1.0, sojourn_s=20.0)
    assert np.array_equal(imm.model_matrices(one, dt)[1], q1)
    # the isotropic model's Q, bit for bit, as before the factor existed: process_noise with D = (s^2, s^2, s^2)
    assert np.array_equal(q1, process_noise(dt, (sigma_j**2,) * 3))


def test_vertical_jerk_factor_is_the_ca_models_only() -> None:
    """The default is 1 (isotropic jerk, the paper's model), left out of a dump; a Singer or CT model refuses any
    other value."""
    assert all(m.vertical_jerk_factor == 1.0 for m in (*CA_MODELS, *MANOEUVRE_MODELS))
    onset = MANOEUVRE_MODELS[-1]  # echoed outputs keep their old form at the default, and a dump reads back
    assert "vertical_jerk_factor" not in onset.model_dump() and "vertical_jerk_factor" not in onset.model_dump_json()
    quiet = MotionModel.model_validate({**onset.model_dump(), "vertical_jerk_factor": 0.1})
    assert quiet.model_dump()["vertical_jerk_factor"] == 0.1
    assert MotionModel.model_validate_json(quiet.model_dump_json()) == quiet
    assert MotionModel.model_validate(onset.model_dump()) == onset
    with pytest.raises(ValueError, match="vertical_jerk_factor"):
        MotionModel(name="s", kind="singer", sigma_accel_mps2=0.2, tau_s=1.0, sojourn_s=200.0, vertical_jerk_factor=0.3)


def heading_exit_bank(dpsi_deg: float, max_sojourn_s: float) -> tuple[MotionModel, ...]:
    """The default bank with the turn's exit by heading change (mean dpsi_deg, longest mean sojourn max_sojourn_s)."""
    return tuple(
        MotionModel.model_validate({**m.model_dump(), "exit_heading_change_deg": dpsi_deg, "sojourn_s": max_sojourn_s})
        if m.kind == "ct"
        else m
        for m in MANOEUVRE_MODELS
    )


@settings(max_examples=80, deadline=None)
@given(
    dt=st.floats(0.1, 30.0),
    omega_dps=st.floats(-20.0, 20.0),
    dpsi=st.floats(10.0, 360.0),
    max_sojourn=st.floats(5.0, 600.0),
    mu=st.lists(st.floats(0.01, 1.0), min_size=3, max_size=3),
)
def test_heading_change_exit_is_the_closed_form(
    dt: float, omega_dps: float, dpsi: float, max_sojourn: float, mu: list[float]
) -> None:
    """A turn whose length in heading is exponential with mean dpsi survives a heading change h with probability
    exp(-h / dpsi); at a turn rate omega over dt, h = |omega| dt. With the longest mean sojourn S as a floor on the
    exit rate, p_turn,turn = min(exp(-|omega| dt / dpsi), exp(-dt / S)); the rest goes to the turn's exits_to
    (straight, onset) equally, every other row is the time-sojourn chain's, and the IMM's predicted model
    probabilities are mu pi with this pi."""
    models = heading_exit_bank(dpsi, max_sojourn)
    rng = np.random.default_rng(3)
    state = imm.ImmState.start(rng.standard_normal(9) * 100.0, random_spd(rng), tuple(np.array(mu) / sum(mu)), models)
    turn = 1
    state.xs[turn, 9] = math.radians(omega_dps)
    pi = imm.transition_matrix(state, models, dt)
    stay = min(math.exp(-abs(omega_dps) * dt / dpsi), math.exp(-dt / max_sojourn))
    assert pi[turn, turn] == pytest.approx(stay, rel=1e-12, abs=1e-300)
    assert pi[turn, 0] == pytest.approx((1.0 - stay) / 2.0, rel=1e-12, abs=1e-15)
    assert pi[turn, 2] == pi[turn, 0]
    assert pi.sum(axis=1) == pytest.approx(np.ones(3), abs=1e-14)
    plain = imm.transition_probabilities(models, dt)
    assert np.array_equal(pi[[0, 2]], plain[[0, 2]])
    # the turn's sign does not matter, and two steps at the same rate are one step of their sum (memoryless)
    state.xs[turn, 9] = -state.xs[turn, 9]
    assert imm.transition_matrix(state, models, dt)[turn, turn] == pi[turn, turn]
    two = imm.transition_matrix(state, models, dt / 2.0)[turn, turn] ** 2
    assert two == pytest.approx(pi[turn, turn], rel=1e-12, abs=1e-300)
    c, _, _ = imm.predict(state, models, dt)
    assert c == pytest.approx(state.mu @ pi, rel=1e-12, abs=1e-300)


def test_heading_change_exit_is_off_by_default_and_the_ct_models_only() -> None:
    """None (the default) leaves the chain of transition_probabilities itself (the same array: bit-identical
    outputs) and is left out of a dump; a value reads back; a CA or Singer model refuses it."""
    assert all(m.exit_heading_change_deg is None for m in (*CA_MODELS, *MANOEUVRE_MODELS))
    rng = np.random.default_rng(4)
    state = imm.ImmState.start(rng.standard_normal(9), random_spd(rng), (0.9, 0.05, 0.05), MANOEUVRE_MODELS)
    state.xs[1, 9] = 0.2
    assert imm.transition_matrix(state, MANOEUVRE_MODELS, 5.0) is imm.transition_probabilities(MANOEUVRE_MODELS, 5.0)
    turn = MANOEUVRE_MODELS[1]
    assert (
        "exit_heading_change_deg" not in turn.model_dump() and "exit_heading_change_deg" not in turn.model_dump_json()
    )
    exit_by_heading = heading_exit_bank(150.0, 120.0)[1]
    assert exit_by_heading.model_dump()["exit_heading_change_deg"] == 150.0
    assert MotionModel.model_validate_json(exit_by_heading.model_dump_json()) == exit_by_heading
    for other in (CA_MODELS[0], MANOEUVRE_MODELS[2]):
        with pytest.raises(ValueError, match="exit_heading_change_deg"):
            MotionModel.model_validate({**other.model_dump(), "exit_heading_change_deg": 150.0})


def test_model_probabilities_follow_a_turn() -> None:
    """A 2 g level turn (60 deg bank, 200 m/s) seen with small noise: the manoeuvre models must take over during the
    turn (probability of the straight model below 0.5) and hand back after it (above 0.5 at the end)."""
    from services.attitude.simulation import FlightPlan, Segment

    plan = FlightPlan(
        (30e3, 4e3, 20e3),
        200.0,
        90.0,
        0.0,
        (
            Segment(100.0),
            Segment(3.0, bank_deg=(0.0, 60.0)),
            Segment(40.0, bank_deg=(60.0, 60.0)),
            Segment(3.0, bank_deg=(60.0, 0.0)),
        ),
    )
    times = scan_times(60, 5.0)
    cfg = AttitudeConfig(radar=None, sigma_r_m=20.0, sigma_az_deg=0.05, sigma_el_deg=0.05)
    meas = measure(fly(plan, times), cfg.measurement_sigmas(), np.random.default_rng(1))[0].tolist()
    core = AttitudeCore(cfg)
    mu = []
    for k, (r, az, el) in enumerate(meas):
        out = core.step(
            RadarPlot(
                header=Header(stamp_ns=round(times[k] * NS)),
                site_id="r1",
                target_id="t",
                range_m=r,
                az_deg=az,
                el_deg=el,
            )
        )[0]
        mu.append(out.model_probabilities[0] if out.model_probabilities else None)
    in_turn = [m for m, t in zip(mu, times, strict=True) if 115.0 <= t <= 140.0 and m is not None]
    assert max(in_turn) < 0.5
    assert mu[-1] is not None and mu[-1] > 0.5


@pytest.mark.parametrize("omega", [math.nan, math.inf, -math.inf])
def test_heading_change_exit_without_a_turn_rate_estimate_keeps_the_longest_sojourn(omega: float) -> None:
    """A turn-rate estimate that is not a number gives the floor exp(-dt / S), never a NaN row."""
    turn = heading_exit_bank(90.0, 60.0)[1]
    assert imm.heading_exit_stay(turn, 5.0, omega) == math.exp(-5.0 / 60.0)
