"""Linear(ised) Kalman filter steps: predict, update in standard and Joseph form, NIS and log-likelihood.

Predict (with an optional known offset b = B u, e.g. a dead-reckoning displacement)::

    x <- F x + b
    P <- F P F^T + Q                         (symmetrised)

Update with a measurement z = H x + v, v ~ N(0, R)::

    y = z - H x                              innovation (``residual(z, H x)`` for angles)
    S = H P H^T + R                          innovation covariance (symmetrised)
    K = P H^T S^-1                           gain, as (S^-1 (P H^T)^T)^T with a linear solve
    x <- x + K y
    P <- (I - K H) P (I - K H)^T + K R K^T   Joseph form: symmetric and PSD for any K (the default)
    P <- (I - K H) P                         standard form: equal to Joseph for the optimal K only

Normalised innovation squared and the Gaussian log-likelihood of the innovation::

    NIS = y^T S^-1 y                         chi^2 with dim(z) degrees of freedom if the filter is consistent
    ln N(y; 0, S) = -1/2 (NIS + ln det S + m ln 2 pi)

Every function takes one estimate (x (n,), P (n, n)) or a batch (x (..., n), P (..., n, n)); H, R, F and Q may be
shared by the batch or given per element. Matrix-vector products are ``A @ v`` for one estimate and an
``einsum`` over the batch.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, cast

import numpy as np
from numpy.typing import NDArray

from .covariance import Floats, symmetrize

FloatArray = NDArray[np.float64]
#: residual(z, Hx) -> y; the default is z - Hx, an angle-aware one wraps some components
Residual = Callable[[FloatArray, FloatArray], FloatArray]
Form = Literal["joseph", "standard"]


def _T(A: Floats) -> FloatArray:
    return cast(FloatArray, np.swapaxes(A, -1, -2))


def matvec(A: Floats, v: Floats) -> FloatArray:
    """A v for one vector (``A @ v``) or a batch (``einsum('...ij,...j->...i')``)."""
    if v.ndim == 1:
        return cast(FloatArray, A @ v)
    return cast(FloatArray, np.einsum("...ij,...j->...i", A, v))


def predict(x: Floats, P: Floats, F: Floats, Q: Floats, b: Floats | None = None) -> tuple[FloatArray, FloatArray]:
    """x <- F x (+ b), P <- sym(F P F^T + Q)."""
    x_new = matvec(F, x)
    if b is not None:
        x_new = x_new + b
    return x_new, symmetrize(F @ P @ _T(F) + Q)


def innovation_covariance(P: Floats, H: Floats, R: Floats) -> FloatArray:
    """S = sym(H P H^T + R)."""
    return symmetrize(H @ P @ _T(H) + R)


def gain(P: Floats, H: Floats, S: Floats) -> FloatArray:
    """K = P H^T S^-1, computed as (S^-1 (P H^T)^T)^T (S symmetric)."""
    return _T(np.linalg.solve(S, _T(P @ _T(H))))


def joseph(P: Floats, K: Floats, H: Floats, R: Floats) -> FloatArray:
    """P <- sym((I - K H) P (I - K H)^T + K R K^T): valid for any gain K."""
    IKH = np.eye(P.shape[-1]) - K @ H
    return symmetrize(IKH @ P @ _T(IKH) + K @ R @ _T(K))


def standard(P: Floats, K: Floats, H: Floats) -> FloatArray:
    """P <- sym((I - K H) P): equal to :func:`joseph` for the optimal gain only."""
    return symmetrize((np.eye(P.shape[-1]) - K @ H) @ P)


def update(
    x: Floats,
    P: Floats,
    z: Floats,
    H: Floats,
    R: Floats,
    residual: Residual | None = None,
    form: Form = "joseph",
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """One Kalman update; returns (x, P, y, S) (module docstring). ``residual`` replaces z - H x."""
    Hx = matvec(H, x)
    y = z - Hx if residual is None else residual(cast(FloatArray, z), Hx)
    S = innovation_covariance(P, H, R)
    K = gain(P, H, S)
    x_new = x + matvec(K, y)
    P_new = joseph(P, K, H, R) if form == "joseph" else standard(P, K, H)
    return x_new, P_new, y, S


def nis(y: Floats, S: Floats) -> FloatArray:
    """NIS = y^T S^-1 y (also the squared Mahalanobis distance of y), batched over the leading axes."""
    return np.einsum("...i,...i->...", y, np.linalg.solve(S, y[..., None])[..., 0])


def log_likelihood(y: Floats, S: Floats) -> FloatArray:
    """ln N(y; 0, S) = -1/2 (NIS + ln det S + m ln 2 pi), batched over the leading axes."""
    m = y.shape[-1]
    _, logdet = np.linalg.slogdet(S)
    return -0.5 * (nis(y, S) + logdet + m * np.log(2.0 * np.pi))
