"""The filter toolkit (shared/filters) pinned to FilterPy on random well-conditioned inputs, plus its invariants.

Inputs: covariances P = A A^T + I with |A_ij| <= 1 (eigenvalues in [1, 1 + n^2], condition number <= 37 for
n <= 6), gains and transitions with entries in [-1, 1]. Two implementations of the same formula then differ by
rounding only: a few products and one solve of a system with condition number c, relative error ~ c * n * eps
~ 37 * 6 * 2.2e-16 ~ 5e-14. The tolerance is rtol = 1e-9 with an absolute floor of 1e-9 times the scale of the
result (for entries that cancel to ~0): four orders of magnitude of margin over rounding, yet a wrong sign,
transpose or weight changes the result at the 1e-2 level or more and fails.
"""

from __future__ import annotations

import math
from unittest import mock

import filterpy.monte_carlo.resampling as fp_resampling
import numpy as np
import pytest
from filterpy.kalman import JulierSigmaPoints, MerweScaledSigmaPoints
from filterpy.kalman import predict as fp_predict
from filterpy.kalman import unscented_transform as fp_ut
from filterpy.kalman import update as fp_update
from filterpy.monte_carlo import stratified_resample as fp_stratified
from filterpy.monte_carlo import systematic_resample as fp_systematic
from filterpy.stats import logpdf
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from shared.filters import angles, covariance, gauss_markov, kalman, resampling, unscented

RTOL = 1e-9
unit = st.floats(-1.0, 1.0, allow_nan=False, allow_subnormal=False)
dims = st.integers(1, 6)


def close(a: object, b: object) -> None:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    np.testing.assert_allclose(a, b, rtol=RTOL, atol=RTOL * max(1.0, float(np.max(np.abs(b)))))


@st.composite
def spd(draw: st.DrawFn, n: int) -> np.ndarray:
    A = draw(arrays(np.float64, (n, n), elements=unit))
    return A @ A.T + np.eye(n)


@st.composite
def kf_case(draw: st.DrawFn) -> tuple[np.ndarray, ...]:
    n, m = draw(dims), draw(st.integers(1, 4))
    x = draw(arrays(np.float64, n, elements=unit))
    z = draw(arrays(np.float64, m, elements=unit))
    H = draw(arrays(np.float64, (m, n), elements=unit))
    return x, draw(spd(n)), z, H, draw(spd(m))


@given(kf_case(), st.data())
@settings(max_examples=150, deadline=None)
def test_predict_matches_filterpy(case: tuple[np.ndarray, ...], data: st.DataObject) -> None:
    x, P, _, _, _ = case
    n = x.size
    F = data.draw(arrays(np.float64, (n, n), elements=unit))
    Q = data.draw(spd(n))
    xf, Pf = fp_predict(x, P, F, Q)
    xk, Pk = kalman.predict(x, P, F, Q)
    close(xk, xf)
    close(Pk, Pf)
    np.testing.assert_array_equal(Pk, Pk.T)  # symmetric to the bit


@given(kf_case())
@settings(max_examples=150, deadline=None)
def test_joseph_update_matches_filterpy(case: tuple[np.ndarray, ...]) -> None:
    x, P, z, H, R = case
    xf, Pf, yf, _, Sf, _ = fp_update(x, P, z, R, H, return_all=True)
    xk, Pk, yk, Sk = kalman.update(x, P, z, H, R)
    close(xk, xf)
    close(Pk, Pf)
    close(yk, yf)
    close(Sk, Sf)
    np.testing.assert_array_equal(Pk, Pk.T)
    assert np.linalg.eigvalsh(Pk).min() > 0.0
    # the posterior is no wider than the prior in any direction: P_prior - P_post is PSD
    assert np.linalg.eigvalsh(P - Pk).min() >= -1e-9 * np.abs(P).max()


@given(kf_case())
@settings(max_examples=150, deadline=None)
def test_standard_form_equals_joseph_for_the_optimal_gain(case: tuple[np.ndarray, ...]) -> None:
    x, P, z, H, R = case
    xj, Pj, _, _ = kalman.update(x, P, z, H, R, form="joseph")
    xs, Ps, _, _ = kalman.update(x, P, z, H, R, form="standard")
    np.testing.assert_array_equal(xj, xs)
    close(Ps, Pj)


@given(kf_case(), arrays(np.float64, 6, elements=unit))
@settings(max_examples=60, deadline=None)
def test_joseph_keeps_psd_for_a_suboptimal_gain(case: tuple[np.ndarray, ...], noise: np.ndarray) -> None:
    _, P, _, H, R = case
    S = kalman.innovation_covariance(P, H, R)
    K = kalman.gain(P, H, S)
    K_bad = K * (1.0 + 0.5 * noise[0]) + 0.1 * noise[1]
    Pj = kalman.joseph(P, K_bad, H, R)
    assert np.linalg.eigvalsh(Pj).min() > 0.0  # (I-KH) P (I-KH)^T + K R K^T >= K R K^T, R > 0


@given(kf_case())
@settings(max_examples=100, deadline=None)
def test_nis_and_log_likelihood(case: tuple[np.ndarray, ...]) -> None:
    x, P, z, H, R = case
    _, _, y, S = kalman.update(x, P, z, H, R)
    close(kalman.nis(y, S), y @ np.linalg.inv(S) @ y)
    close(kalman.log_likelihood(y, S), logpdf(y, cov=S))
    # batched == one by one
    yb, Sb = np.stack([y, 2.0 * y]), np.stack([S, 3.0 * S])
    close(kalman.nis(yb, Sb), [kalman.nis(y, S), kalman.nis(2.0 * y, 3.0 * S)])


def test_batched_update_equals_single() -> None:
    rng = np.random.default_rng(3)
    B, n, m = 5, 4, 2
    A = rng.uniform(-1, 1, (B, n, n))
    P = A @ np.swapaxes(A, -1, -2) + np.eye(n)
    x, z = rng.uniform(-1, 1, (B, n)), rng.uniform(-1, 1, (B, m))
    H, R = rng.uniform(-1, 1, (m, n)), np.eye(m)
    xb, Pb, _, _ = kalman.update(x, P, z, H, R)
    for b in range(B):
        xs, Ps, _, _ = kalman.update(x[b], P[b], z[b], H, R)
        close(xb[b], xs)
        close(Pb[b], Ps)


@given(dims, st.data(), st.floats(0.1, 1.0), st.floats(0.0, 2.0), st.floats(0.0, 3.0))
@settings(max_examples=100, deadline=None)
def test_merwe_points_and_transform_match_filterpy(
    n: int, data: st.DataObject, alpha: float, beta: float, kappa: float
) -> None:
    m = data.draw(arrays(np.float64, n, elements=unit))
    P = data.draw(spd(n))
    X, Wm, Wc = unscented.merwe_scaled_sigma_points(m, P, alpha, beta, kappa)
    ref = MerweScaledSigmaPoints(n, alpha=alpha, beta=beta, kappa=kappa)
    close(X, ref.sigma_points(m, P))
    close(Wm, ref.Wm)
    close(Wc, ref.Wc)
    Y = np.column_stack([np.sin(X[:, 0]), X @ np.arange(1.0, n + 1.0), X[:, -1] ** 2])  # a nonlinear f
    y, Py = unscented.weighted_transform(Y, Wm, Wc, np.eye(3))
    yf, Pyf = fp_ut(Y, ref.Wm, ref.Wc, np.eye(3))
    close(y, yf)
    close(Py, Pyf)


@given(dims, st.data())
@settings(max_examples=100, deadline=None)
def test_paper_ut_is_julier_with_kappa_zero(n: int, data: st.DataObject) -> None:
    """The symmetric equal-weight set = Julier's set with kappa = 0 (its central point has weight 0)."""
    m = data.draw(arrays(np.float64, n, elements=unit))
    P = data.draw(spd(n))
    ref = JulierSigmaPoints(n, kappa=0.0)
    pts = ref.sigma_points(m, P)
    assert ref.Wm[0] == 0.0
    X = unscented.sigma_points(m[None, :], P[None, :, :])[0]
    close(X, pts[1:])

    def f(v: np.ndarray) -> np.ndarray:
        return np.stack([v[..., 0] * v[..., -1], np.exp(0.3 * v[..., 0])], axis=-1)

    res = unscented.unscented_transform(m[None, :], P[None, :, :], f)
    yf, Pyf = fp_ut(f(pts), ref.Wm, ref.Wc)
    close(res.mean[0], yf)
    close(res.cov[0], Pyf)
    # cross-covariance sum W (X - m)(Y - y)^T; a linear f gives P_xy = P A^T exactly in exact arithmetic
    A = np.arange(2.0 * n).reshape(2, n) / n
    lin = unscented.unscented_transform(m[None, :], P[None, :, :], lambda v: v @ A.T)
    close(lin.cross[0], P @ A.T)
    close(lin.cov[0], A @ P @ A.T)


def test_ut_angle_output_is_rotation_invariant() -> None:
    """Averaging an azimuth across the +-pi cut: the wrapped mean equals the mean away from the cut, rotated."""
    m = np.array([[0.0, 1.0]])
    P = np.array([[[0.04, 0.0], [0.0, 0.01]]])

    def f(rot: float):  # type: ignore[no-untyped-def]
        return lambda v: np.stack([v[..., 1], angles.wrap_pi(v[..., 0] + rot)], axis=-1)

    base = unscented.unscented_transform(m, P, f(0.0), az_index=1)
    cut = unscented.unscented_transform(m, P, f(math.pi), az_index=1)
    assert abs(angles.wrap_pi(cut.mean[0, 1] - math.pi) - base.mean[0, 1]) < 1e-12
    close(cut.cov, base.cov)


def test_linearized_transform_of_a_linear_map_is_exact() -> None:
    rng = np.random.default_rng(5)
    A = rng.uniform(-1, 1, (3, 4))
    m = rng.uniform(-1, 1, (2, 4))
    L = rng.uniform(-1, 1, (2, 4, 4))
    P = L @ np.swapaxes(L, -1, -2) + np.eye(4)
    res = unscented.linearized_transform(m, P, lambda v: v @ A.T)
    np.testing.assert_allclose(res.cov, A @ P @ A.T, rtol=1e-8, atol=1e-8)  # central differences: O(h^2) = 0


@given(arrays(np.float64, (4, 3, 3), elements=unit))
def test_symmetrize_and_robust_cholesky(A: np.ndarray) -> None:
    S = covariance.symmetrize(A)
    np.testing.assert_array_equal(S, np.swapaxes(S, -1, -2))
    np.testing.assert_array_equal(covariance.symmetrize(S), S)  # idempotent to the bit
    P = A @ np.swapaxes(A, -1, -2)  # PSD, possibly singular
    stats = covariance.CholeskyStats()
    D = covariance.robust_cholesky(P, stats)
    assert np.isfinite(D).all()
    np.testing.assert_allclose(D @ np.swapaxes(D, -1, -2), P, atol=1e-6 * max(1.0, np.abs(P).max()))
    assert covariance.is_positive_definite(P[0] + np.eye(3))
    assert not covariance.is_positive_definite(-np.eye(3))


def test_robust_cholesky_clips_an_indefinite_matrix() -> None:
    P = np.array([[[1.0, 0.0], [0.0, -1e-3]]])
    stats = covariance.CholeskyStats()
    D = covariance.robust_cholesky(P, stats)
    assert stats.eig_clip == 1
    np.testing.assert_allclose(D[0] @ D[0].T, [[1.0, 0.0], [0.0, 0.0]], atol=1e-15)


finite_angle = st.floats(-1e4, 1e4, allow_nan=False)


@given(finite_angle)
def test_wrap_in_range_idempotent_and_congruent(a: float) -> None:
    eps = 8 * np.finfo(float).eps * max(1.0, abs(a))  # one rounding of a, pi - a and the mod
    for wrap, lo, hi in (
        (angles.wrap_pi, -math.pi, math.pi),
        (angles.wrap_pi_left, -math.pi, math.pi),
        (angles.wrap_2pi, 0.0, 2 * math.pi),
    ):
        w = float(wrap(a))
        assert lo <= w <= hi
        assert abs(float(wrap(w)) - w) <= 8 * np.finfo(float).eps * math.pi or abs(abs(w) - math.pi) < 1e-12
        k = (a - w) / (2 * math.pi)
        assert abs(k - round(k)) * 2 * math.pi <= eps + 1e-15
    d = float(angles.wrap_deg_180(a))
    assert -180.0 < d <= 180.0
    assert abs(((a - d) / 360.0) - round((a - d) / 360.0)) * 360.0 <= 1e-10 * max(1.0, abs(a))


def test_wrap_end_points() -> None:
    assert float(angles.wrap_pi(math.pi)) == math.pi  # (-pi, pi]
    assert float(angles.wrap_pi(-math.pi)) == math.pi
    assert float(angles.wrap_pi_left(math.pi)) == -math.pi  # [-pi, pi)
    assert float(angles.wrap_deg_180(-180.0)) == 180.0
    assert float(angles.wrap_2pi(-1e-300)) == 0.0 or float(angles.wrap_2pi(-1e-300)) < 2 * math.pi


@given(arrays(np.float64, st.integers(1, 60), elements=st.floats(1e-3, 1.0)), st.integers(0, 2**31))
@settings(max_examples=150)
def test_resampling_matches_filterpy(raw: np.ndarray, seed: int) -> None:
    w = raw / raw.sum()
    for ours, ref, draw in (
        (resampling.systematic_resample, fp_systematic, lambda r: r.random()),
        (resampling.stratified_resample, fp_stratified, lambda r: r.random(w.size)),
    ):
        idx = ours(w, np.random.Generator(np.random.MT19937(seed)))
        # FilterPy draws from numpy's global RandomState (``random`` bound in its module): give it the same uniforms
        u = draw(np.random.Generator(np.random.MT19937(seed)))
        with mock.patch.object(fp_resampling, "random", lambda *_, u=u: u):
            try:
                expect = ref(w)
            except IndexError:  # FilterPy does not clamp the last cumulative sum to 1: it can run off the end
                assume(False)
        np.testing.assert_array_equal(idx, expect)
        counts = np.bincount(idx, minlength=w.size)
        assert np.all(np.abs(counts - w.size * w) < (1.0 if ours is resampling.systematic_resample else 2.0))


def test_effective_sample_size() -> None:
    assert resampling.effective_sample_size(np.full(10, 0.1)) == pytest.approx(10.0, rel=1e-12)
    assert resampling.effective_sample_size(np.array([1.0, 0.0, 0.0])) == 1.0


def test_gauss_markov_discretisation() -> None:
    a, q = gauss_markov.discretise(2.0, 10.0, 0.5)
    assert a == pytest.approx(math.exp(-0.2), rel=1e-15)
    assert q == pytest.approx(0.25 * (1 - math.exp(-0.4)), rel=1e-14)  # stationary: a^2 s^2 + q = s^2
    a_e, q_e = gauss_markov.discretise(0.01, 10.0, 0.5, "euler")
    a_x, q_x = gauss_markov.discretise(0.01, 10.0, 0.5)
    assert abs(a_e - a_x) < 1e-6 and abs(q_e - q_x) / q_x < 2e-3  # first order in dt/tau = 1e-3
    a_v, sd_v = gauss_markov.discretise_sd(2.0, np.array([10.0, 5.0]), np.array([0.5, 1.0]))
    np.testing.assert_allclose(a_v, np.exp([-0.2, -0.4]), rtol=1e-15)
    np.testing.assert_allclose(sd_v**2, [q, 1.0 - math.exp(-0.8)], rtol=1e-14)


def test_gauss_markov_path_statistics() -> None:
    """Sample variance sigma^2 and lag-1 correlation a of a long path, within 5 standard errors."""
    n, sigma, tau, dt = 200_000, 2.0, 5.0, 1.0
    x = gauss_markov.path(np.random.default_rng(11), n, sigma, tau, dt)
    a = math.exp(-dt / tau)
    n_eff = n * (1 - a) / (1 + a)  # effective samples of an AR(1) path for the variance
    assert abs(x.var() / sigma**2 - 1.0) < 5 * math.sqrt(2.0 / n_eff)
    rho = float(np.corrcoef(x[:-1], x[1:])[0, 1])
    assert abs(rho - a) < 5 * (1 - a * a) / math.sqrt(n)
    assert gauss_markov.path(np.random.default_rng(0), 0, 1.0, 1.0, 1.0).size == 0


# ---------------------------------------------------------------- forms added for the attitude estimator
@st.composite
def selection_case(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray, slice, np.ndarray]:
    """An n-state (3..10) with a 3-D measurement of the components idx = start::step (H = I[idx])."""
    step = draw(st.integers(1, 3))
    n = draw(st.integers(2 * step + 1, 10))
    start = draw(st.integers(0, n - 1 - 2 * step))
    idx = slice(start, start + 3 * step, step)
    x = draw(arrays(np.float64, n, elements=unit))
    z = draw(arrays(np.float64, 3, elements=unit))
    return x, draw(spd(n)), z, idx, draw(spd(3))


@given(selection_case())
@settings(max_examples=150, deadline=None)
def test_update_selection_matches_filterpy(case: tuple[np.ndarray, np.ndarray, np.ndarray, slice, np.ndarray]) -> None:
    x, P, z, idx, R = case
    H = np.eye(x.size)[idx]
    assert H.shape == (3, x.size)
    xf, Pf, yf, _, Sf, _ = fp_update(x, P, z, R, H, return_all=True)
    xk, Pk, yk, nis = kalman.update_selection(x, P, z, idx, R)
    close(xk, xf)
    close(Pk, Pf)
    close(yk, yf)
    close(nis, yf @ np.linalg.inv(Sf) @ yf)
    np.testing.assert_array_equal(Pk, Pk.T)  # symmetric to the bit
    xj, Pj, _, _ = kalman.update(x, P, z, H, R)  # the general Joseph update, up to rounding
    close(xk, xj)
    close(Pk, Pj)


@given(spd(3), arrays(np.float64, 3, elements=unit))
@settings(max_examples=100, deadline=None)
def test_whitening_nis_and_likelihood_of_a_3d_innovation(S: np.ndarray, y: np.ndarray) -> None:
    W = kalman.whitening_3x3(S)
    np.testing.assert_array_equal(W, np.tril(W))
    close(W @ S @ W.T, np.eye(3))  # W = L^-1: W S W^T = I
    close(kalman.nis_solve(y, S), y @ np.linalg.inv(S) @ y)
    close(kalman.det_3x3(S), np.linalg.det(S))
    close(kalman.log_likelihood_3(kalman.nis_solve(y, S), S), logpdf(y, cov=S))


def test_whitening_refuses_a_matrix_that_is_not_positive_definite() -> None:
    for S in (np.diag([1.0, -1.0, 1.0]), np.diag([0.0, 1.0, 1.0]), np.full((3, 3), np.nan), np.ones((3, 3))):
        with pytest.raises(np.linalg.LinAlgError):
            kalman.whitening_3x3(S)


@given(kf_case(), st.data())
@settings(max_examples=100, deadline=None)
def test_unsymmetrised_prediction(case: tuple[np.ndarray, ...], data: st.DataObject) -> None:
    """symmetrise=False returns F P F^T + Q before the symmetrisation: symmetrising it gives predict's P to the bit."""
    x, P, _, _, _ = case
    n = x.size
    F = data.draw(arrays(np.float64, (n, n), elements=unit))
    Q = data.draw(spd(n))
    xs, Ps = kalman.predict(x, P, F, Q)
    xu, Pu = kalman.predict(x, P, F, Q, symmetrise=False)
    np.testing.assert_array_equal(xu, xs)
    np.testing.assert_array_equal(covariance.symmetrize(Pu), Ps)
    _, Pf = fp_predict(x, P, F, Q)
    close(Pu, Pf)
    np.testing.assert_array_equal(kalman.predict_covariance(P, F, Q, symmetrise=False), Pu)


@given(finite_angle)
def test_wrap_pi_shifted(a: float) -> None:
    """(-pi, pi], congruent to a; the [-pi, pi) formula except that -pi becomes pi."""
    w = float(angles.wrap_pi_shifted(a))
    assert -math.pi < w <= math.pi
    k = (a - w) / (2 * math.pi)
    assert abs(k - round(k)) * 2 * math.pi <= 8 * np.finfo(float).eps * max(1.0, abs(a)) + 1e-15
    left = float(angles.wrap_pi_left(a))
    assert w == (math.pi if left == -math.pi else left)


def test_wrap_pi_shifted_end_points() -> None:
    assert float(angles.wrap_pi_shifted(math.pi)) == math.pi
    assert float(angles.wrap_pi_shifted(-math.pi)) == math.pi
    assert float(angles.wrap_pi_shifted(3 * math.pi)) == math.pi
    np.testing.assert_array_equal(angles.wrap_pi_shifted(np.array([0.0, -0.5])), [0.0, -0.5])


@given(arrays(np.float64, (4, 4), elements=unit), st.floats(-2.0, 2.0))
def test_is_cholesky_factorable(A: np.ndarray, shift: float) -> None:
    """Agrees with the eigenvalue test away from the margin (min eigenvalue not within 1e-9 of 0)."""
    P = A @ A.T + shift * np.eye(4)
    lam = float(np.linalg.eigvalsh(P).min())
    assume(abs(lam) > 1e-9)
    assert covariance.is_cholesky_factorable(P) == (lam > 0.0) == covariance.is_positive_definite(P)
    P[1, 2] = np.nan
    assert not covariance.is_cholesky_factorable(P)
