"""Sigma points and the unscented transform (Julier & Uhlmann; Van der Merwe's scaled set), with a first-order
counterpart, batched over a leading dimension B.

Van der Merwe's scaled sigma points of N(m, P) (n states), lambda = alpha^2 (n + kappa) - n::

    X_0 = m,   X_i = m + [sqrt((n + lambda) P)]_i,   X_{n+i} = m - [sqrt((n + lambda) P)]_i      (i = 1..n)
    Wm_0 = lambda / (n + lambda),   Wc_0 = Wm_0 + 1 - alpha^2 + beta,   Wm_i = Wc_i = 1 / (2 (n + lambda))

and the unscented transform of the propagated points Y_i = f(X_i)::

    y = sum_i Wm_i Y_i,   P_y = sum_i Wc_i (Y_i - y)(Y_i - y)^T (+ noise),   P_xy = sum_i Wc_i (X_i - m)(Y_i - y)^T

The symmetric set of digest 003 §2.2 (PCL tracker) is the case alpha = 1, beta = 0, kappa = 0: lambda = 0, so the
central point has weight 0 and is left out; the 2n points ``m ± sqrt(n) D[:, i]`` (P = D D^T) have equal weights
1/(2n) (:func:`sigma_points`, :func:`unscented_transform`). Angle outputs (``az_index``) are averaged relative to
``f(m)`` with wrapped differences, so the result is invariant under a rotation of the angle.
:func:`linearized_transform` is the first-order (EKF) counterpart y = f(m), P_y = J P J^T with a central-difference
Jacobian J.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .angles import wrap_pi
from .covariance import CholeskyStats, FloatArray, robust_cholesky, symmetrize

__all__ = [
    "CholeskyStats",
    "PointMap",
    "TransformResult",
    "linearized_transform",
    "merwe_scaled_sigma_points",
    "moments_from_points",
    "numerical_jacobian",
    "sigma_points",
    "symmetrize",
    "transform",
    "unscented_transform",
    "weighted_transform",
]

#: f maps points (..., n) to outputs (..., k)
PointMap = Callable[[FloatArray], FloatArray]


def merwe_scaled_sigma_points(
    m: FloatArray, P: FloatArray, alpha: float, beta: float, kappa: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Van der Merwe's 2n + 1 scaled sigma points of N(m (n,), P (n, n)): (points (2n+1, n), Wm, Wc).

    The square root is the lower Cholesky factor L of (n + lambda) P, X_i = m + L[:, i] (FilterPy takes the
    rows of the upper factor L^T: the same points).
    """
    n = m.shape[-1]
    lam = alpha * alpha * (n + kappa) - n
    L = np.linalg.cholesky((n + lam) * P)
    X = np.vstack([m[None, :], m[None, :] + L.T, m[None, :] - L.T])
    Wm = np.full(2 * n + 1, 0.5 / (n + lam))
    Wc = Wm.copy()
    Wm[0] = lam / (n + lam)
    Wc[0] = lam / (n + lam) + (1.0 - alpha * alpha + beta)
    return X, Wm, Wc


def weighted_transform(
    Y: FloatArray, Wm: FloatArray, Wc: FloatArray, noise_cov: FloatArray | None = None
) -> tuple[FloatArray, FloatArray]:
    """Weighted moments of propagated sigma points Y (N, k): y = sum Wm Y, P_y = sum Wc (Y - y)(Y - y)^T + noise."""
    y = Wm @ Y
    d = Y - y[None, :]
    P = (d.T * Wc) @ d
    if noise_cov is not None:
        P = P + noise_cov
    return y, P


def sigma_points(m: FloatArray, P: FloatArray, stats: CholeskyStats | None = None) -> FloatArray:
    """The 2n symmetric sigma points (B, 2n, n): m + sqrt(n) D[:, i], then m - sqrt(n) D[:, i] (P = D D^T)."""
    n = m.shape[-1]
    D = robust_cholesky(P, stats)
    off = np.sqrt(n) * np.swapaxes(D, -1, -2)  # row i = column i of D
    return np.concatenate([m[:, None, :] + off, m[:, None, :] - off], axis=1)


@dataclass
class TransformResult:
    """Mean (B, k), covariance (B, k, k) and input-output cross-covariance (B, n, k) of y = f(x).

    ``cross`` is empty, shape (B, 0, 0), when the caller did not ask for it (``with_cross=False``): only the
    optional 4-D bistatic UKF update uses it, and leaving it out saves a third of the moment computation.
    """

    mean: FloatArray
    cov: FloatArray
    cross: FloatArray


def unscented_transform(
    m: FloatArray,
    P: FloatArray,
    f: PointMap,
    az_index: int | None = None,
    stats: CholeskyStats | None = None,
    with_cross: bool = True,
) -> TransformResult:
    """Paper UT of a batch: m (B, n), P (B, n, n) through f; weights 1/(2n), no central point."""
    X = sigma_points(m, P, stats)
    if az_index is None:
        return moments_from_points(m, X, f(X), with_cross=with_cross)
    G = f(np.concatenate([X, m[:, None, :]], axis=1))  # one call: the 2n points and the mean (azimuth ref)
    return moments_from_points(m, X, G[:, :-1, :], az_index, G[:, -1, az_index], with_cross)


def moments_from_points(
    m: FloatArray,
    X: FloatArray,
    G: FloatArray,
    az_index: int | None = None,
    az_ref: FloatArray | None = None,
    with_cross: bool = True,
) -> TransformResult:
    """Equal-weight moments of propagated sigma points G = f(X) (B, 2n, k) around the input mean m.

    With ``az_index``, the azimuth outputs are unwrapped around ``az_ref`` (B,) (normally f(m)) first.
    """
    n = m.shape[-1]
    G = np.array(G, dtype=np.float64, copy=True)
    if az_index is not None:
        ref = az_ref if az_ref is not None else G[:, 0, az_index]
        G[..., az_index] = ref[:, None] + wrap_pi(G[..., az_index] - ref[:, None])
    g = G.mean(axis=1)
    dG = G - g[:, None, :]
    cov = symmetrize(np.einsum("bik,bil->bkl", dG, dG) / (2 * n))
    no_cross = np.zeros((G.shape[0], 0, 0))
    cross = np.einsum("bik,bil->bkl", X - m[:, None, :], dG) / (2 * n) if with_cross else no_cross
    if az_index is not None:
        g[:, az_index] = wrap_pi(g[:, az_index])
    return TransformResult(g, cov, cross)


def numerical_jacobian(m: FloatArray, f: PointMap, az_index: int | None = None) -> FloatArray:
    """Central-difference Jacobian (B, k, n) of f at m (B, n); azimuth differences are wrapped."""
    n = m.shape[-1]
    h = 1e-6 * np.maximum(np.abs(m), 1.0)  # (B, n)
    E = np.eye(n)
    pts = np.concatenate([m[:, None, :] + h[:, None, :] * E, m[:, None, :] - h[:, None, :] * E], axis=1)
    G = f(pts)
    dG = G[:, :n, :] - G[:, n:, :]  # (B, n, k)
    if az_index is not None:
        dG[..., az_index] = wrap_pi(dG[..., az_index])
    return np.swapaxes(dG / (2.0 * h[:, :, None]), -1, -2)


def linearized_transform(m: FloatArray, P: FloatArray, f: PointMap, az_index: int | None = None) -> TransformResult:
    """First-order (EKF-style) counterpart of the UT: y = f(m), P_y = J P J^T (digest §3.4, test C5)."""
    g = f(m).copy()
    J = numerical_jacobian(m, f, az_index)
    cross = P @ np.swapaxes(J, -1, -2)
    cov = symmetrize(J @ cross)
    if az_index is not None:
        g[:, az_index] = wrap_pi(g[:, az_index])
    return TransformResult(g, cov, cross)


def transform(
    kind: str,
    m: FloatArray,
    P: FloatArray,
    f: PointMap,
    az_index: int | None = None,
    stats: CholeskyStats | None = None,
    with_cross: bool = True,
) -> TransformResult:
    """Dispatch on the configured transform: ``"unscented"`` (paper) or ``"linearized"``."""
    if kind == "unscented":
        return unscented_transform(m, P, f, az_index, stats, with_cross)
    if kind == "linearized":
        return linearized_transform(m, P, f, az_index)
    raise ValueError(f"unknown transform {kind!r}")
