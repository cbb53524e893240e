"""The IMM of the PCL tracker (services/pcl_tracker/imm.py) against independent computations.

* r identical models: the IMM is exactly the single CV filter (mixing identical Gaussians changes nothing);
* a 2- and a 3-model IMM against filterpy's ``IMMEstimator`` (an independent implementation, loops over
  ``KalmanFilter`` objects) on the same measurements: every model's state and covariance and the model
  probabilities after each update;
* properties (Hypothesis): the switching matrix is stochastic, mixing keeps probability mass and positive
  definite covariances, the moment-matched mixture equals the sample moments of the mixture;
* the mixture of bistatic predictions averages azimuths across the ±180° cut like the scene rotated by 90°.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import IMMEstimator, KalmanFilter
from hypothesis import given, settings
from hypothesis import strategies as st

from services.pcl_tracker.filter import kf_position_update, predict
from services.pcl_tracker.imm import (
    ImmModels,
    combine,
    combine_measurements,
    imm_position_update,
    imm_predict,
    mix,
    switching_matrix,
)
from services.pcl_tracker.models import H_POS, cv_process_noise, cv_transition

TAU = 3.0


def random_spd(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    A = rng.standard_normal((n, n))
    return scale * (A @ A.T + n * np.eye(n))


def measurements(rng: np.random.Generator, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """A target straight for 10 scans, then turning at 2 g (200 m/s, 0.1 rad/s), seen through converted-position
    noise (y, R) per scan."""
    out = []
    for k in range(n):
        t = max(k - 10, 0) * TAU
        p = np.array([20_000.0 + 2000.0 * math.sin(0.1 * t), 30_000.0 + 2000.0 * math.cos(0.1 * t), 3000.0])
        p[0] += 200.0 * TAU * min(k - 10, 0)
        R = random_spd(rng, 3, 4000.0)
        out.append((p + np.linalg.cholesky(R) @ rng.standard_normal(3), R))
    return out


def run_ours(models: ImmModels, x0: np.ndarray, P0: np.ndarray, meas: list) -> list:
    r = models.r
    mu = np.array(models.mu0)[None]
    xm = np.repeat(x0[None, None], r, axis=1)
    Pm = np.repeat(P0[None, None], r, axis=1)
    out = []
    for y, R in meas:
        c, xm, Pm = imm_predict(mu, xm, Pm, np.array([TAU]), models)
        mu, xm, Pm = imm_position_update(c, xm, Pm, y[None], R[None])
        out.append((mu[0].copy(), xm[0].copy(), Pm[0].copy(), *combine(mu, xm, Pm)))
    return out


def test_identical_models_equal_the_single_filter() -> None:
    rng = np.random.default_rng(1)
    x0 = np.array([20_000.0, 32_000.0, 3000.0, 150.0, -80.0, 0.0])
    P0 = random_spd(rng, 6, 100.0)
    meas = measurements(rng, 25)
    models = ImmModels((4.0, 4.0, 4.0), (30.0, 60.0, 10.0), (0.2, 0.5, 0.3))
    ours = run_ours(models, x0, P0, meas)
    x, P = x0[None], P0[None]
    for (y, R), (mu, _, _, xc, Pc) in zip(meas, ours, strict=True):
        x, P = predict(x, P, np.array([TAU]), 4.0)
        x, P, _ = kf_position_update(x, P, y[None], R[None])
        np.testing.assert_allclose(xc[0], x[0], rtol=1e-11, atol=1e-7)  # m, m/s: rounding of the mixing sums
        np.testing.assert_allclose(Pc[0], P[0], rtol=1e-9, atol=1e-9)
        # equal likelihoods: mu_j = c_j, and the switching of a 3-model chain keeps mu at its stationary mix
        assert mu.sum() == pytest.approx(1.0, abs=1e-12)


def filterpy_imm(models: ImmModels, x0: np.ndarray, P0: np.ndarray) -> IMMEstimator:
    filters = []
    for q in models.q_m2s4:
        kf = KalmanFilter(dim_x=6, dim_z=3)
        kf.x = x0.copy()
        kf.P = P0.copy()
        kf.F = cv_transition(TAU)[0]
        kf.Q = cv_process_noise(TAU, q)[0]
        kf.H = H_POS.copy()
        filters.append(kf)
    M = switching_matrix(np.array([TAU]), models.sojourn_s)[0]  # M[i, j] = P(i -> j), as filterpy expects
    return IMMEstimator(filters, np.array(models.mu0), M)


@pytest.mark.parametrize(
    "models",
    [
        ImmModels((0.01, 400.0), (600.0, 15.0), (0.9, 0.1)),
        ImmModels((0.001, 25.0, 400.0), (1200.0, 60.0, 15.0), (0.6, 0.2, 0.2)),
    ],
)
def test_imm_matches_filterpy(models: ImmModels) -> None:
    rng = np.random.default_rng(7)
    x0 = np.array([18_000.0, 32_000.0, 3000.0, 200.0, 0.0, 0.0])
    P0 = random_spd(rng, 6, 400.0)
    meas = measurements(rng, 30)
    ref = filterpy_imm(models, x0, P0)
    mu_high = []
    for (y, R), (mu, xm, Pm, xc, Pc) in zip(meas, run_ours(models, x0, P0, meas), strict=True):
        ref.predict()
        for f in ref.filters:
            f.R = R
        ref.update(y)
        mu_high.append(mu[-1])
        np.testing.assert_allclose(mu, ref.mu, rtol=1e-8, atol=1e-12)
        for j, f in enumerate(ref.filters):
            np.testing.assert_allclose(xm[j], f.x, rtol=1e-10, atol=1e-6)
            np.testing.assert_allclose(Pm[j], f.P, rtol=1e-8, atol=1e-6)
        np.testing.assert_allclose(xc[0], ref.x, rtol=1e-10, atol=1e-6)
        np.testing.assert_allclose(Pc[0], ref.P, rtol=1e-8, atol=1e-6)
    assert min(mu_high[3:10]) < 0.2 < 0.8 < max(mu_high[10:])  # the run exercised switching: straight, then turn


# ------------------------------------------------------------------------------------------------ properties
probabilities = st.lists(st.floats(0.0, 1.0), min_size=2, max_size=5).filter(lambda v: sum(v) > 1e-3)


@settings(max_examples=60, deadline=None)
@given(
    tau=st.floats(0.0, 1e4),
    sojourn=st.lists(st.floats(1e-3, 1e5), min_size=1, max_size=6),
)
def test_switching_matrix_is_stochastic(tau: float, sojourn: list[float]) -> None:
    Pi = switching_matrix(np.array([tau]), tuple(sojourn))[0]
    assert np.all(Pi >= 0.0) and np.all(Pi <= 1.0)
    np.testing.assert_allclose(Pi.sum(axis=1), 1.0, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(w=probabilities, seed=st.integers(0, 2**31), spread=st.floats(1e-3, 1e6), tau=st.floats(0.0, 600.0))
def test_mixing_keeps_mass_and_positive_definite_covariances(
    w: list[float], seed: int, spread: float, tau: float
) -> None:
    rng = np.random.default_rng(seed)
    r = len(w)
    mu = np.array(w)[None] / sum(w)
    xm = rng.standard_normal((1, r, 6)) * spread
    Pm = np.stack([random_spd(rng, 6, spread) for _ in range(r)])[None]
    Pi = switching_matrix(np.array([tau]), tuple(rng.uniform(1.0, 100.0, r)))
    c, _, P0 = mix(mu, xm, Pm, Pi)
    assert c.sum() == pytest.approx(1.0, abs=1e-9)
    for j in range(r):
        np.testing.assert_array_equal(P0[0, j], P0[0, j].T)
        assert np.linalg.eigvalsh(P0[0, j]).min() > 0.0
    models = ImmModels((0.0,) * r, (50.0,) * r, tuple(mu[0]))
    _, xp, Pp = imm_predict(mu, xm, Pm, np.array([tau]), models)
    assert np.all(np.isfinite(xp)) and np.all(np.isfinite(Pp))


@settings(max_examples=40, deadline=None)
@given(w=probabilities, seed=st.integers(0, 2**31))
def test_moment_matching_equals_the_mixture_moments(w: list[float], seed: int) -> None:
    """x = E[x], P = E[(x - x̄)(x - x̄)^T] of the mixture, computed from its definition by the law of total
    covariance in a different order: E[x x^T] - x̄ x̄^T with E[x x^T] = sum_j w_j (P_j + x_j x_j^T)."""
    rng = np.random.default_rng(seed)
    r = len(w)
    wn = np.array(w) / sum(w)
    xm = rng.standard_normal((r, 3)) * 10.0
    Pm = np.stack([random_spd(rng, 3) for _ in range(r)])
    x, P = combine(wn[None], xm[None], Pm[None])
    second = sum(wn[j] * (Pm[j] + np.outer(xm[j], xm[j])) for j in range(r))
    np.testing.assert_allclose(x[0], wn @ xm, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(P[0], second - np.outer(wn @ xm, wn @ xm), rtol=1e-9, atol=1e-9)


def test_mixture_of_bistatic_predictions_is_wrap_safe() -> None:
    """Two models' azimuths at +179° and -179°: their mixture lies at 180°, as the same scene rotated by 90°
    (azimuths 89° and 91°) gives 90°; the covariances agree."""
    c = np.array([[0.25, 0.75]])
    S = np.stack([np.diag([100.0, 1e-4, 1e-4, 4.0]), np.diag([200.0, 2e-4, 1e-4, 9.0])])[None]
    z_cut = np.array([[[5000.0, math.radians(179.0), 0.1, 50.0], [5100.0, math.radians(-179.0), 0.1, 60.0]]])
    z_rot = z_cut.copy()
    z_rot[..., 1] = np.array([math.radians(89.0), math.radians(91.0)])
    zc, Sc = combine_measurements(c, z_cut, S)
    zr, Sr = combine_measurements(c, z_rot, S)
    d = (zc[0, 1] - zr[0, 1] - math.pi / 2 + math.pi) % (2 * math.pi) - math.pi
    assert abs(d) < 1e-12
    np.testing.assert_allclose(np.delete(zc[0], 1), np.delete(zr[0], 1), rtol=1e-12)
    np.testing.assert_allclose(Sc, Sr, rtol=1e-9, atol=1e-15)
