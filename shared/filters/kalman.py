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

A measurement of some components of the state (H = I[idx], rows of the identity: positions out of a kinematic
state) has the same update with the products by H done by indexing (exact: H only selects), and for m = 3 the
gain through the closed-form Cholesky factor S = L L^T, W = L^-1 (:func:`update_selection`)::

    P H^T = P[:, idx],   S = P[idx, idx] + R,   K = (P H^T W^T) W,   NIS = |W y|^2

Every function takes one estimate (x (n,), P (n, n)) or a batch (x (..., n), P (..., n, n)); H, R, F and Q may be
shared by the batch or given per element. Matrix-vector products are ``A @ v`` for one estimate and an
``einsum`` over the batch.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache
from typing import Literal, cast

import numpy as np
from numpy.typing import NDArray

from .covariance import Floats, symmetrize, transpose

FloatArray = NDArray[np.float64]
#: residual(z, Hx) -> y; the default is z - Hx, an angle-aware one wraps some components
Residual = Callable[[FloatArray, FloatArray], FloatArray]
Form = Literal["joseph", "standard"]


_T = transpose


def matvec(A: Floats, v: Floats) -> FloatArray:
    """A v for one vector (``A @ v``) or a batch (``einsum('...ij,...j->...i')``)."""
    if v.ndim == 1:
        return cast(FloatArray, A @ v)
    return cast(FloatArray, np.einsum("...ij,...j->...i", A, v))


def predict(
    x: Floats, P: Floats, F: Floats, Q: Floats, b: Floats | None = None, symmetrise: bool = True
) -> tuple[FloatArray, FloatArray]:
    """x <- F x (+ b), P <- sym(F P F^T + Q) (:func:`predict_covariance`)."""
    x_new = F @ x if x.ndim == 1 else matvec(F, x)  # matvec's one-vector case, without its call
    if b is not None:
        x_new = x_new + b
    return x_new, predict_covariance(P, F, Q, symmetrise)


def predict_covariance(P: Floats, F: Floats, Q: Floats, symmetrise: bool = True) -> FloatArray:
    """P <- sym(F P F^T + Q), products left to right. ``symmetrise=False`` leaves the rounding's asymmetry in
    place: for a prediction that an update (which symmetrises its result) follows at once."""
    P_new: FloatArray = F @ P @ _T(F) + Q
    return symmetrize(P_new) if symmetrise else P_new


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


def nis_solve(y: Floats, S: Floats) -> float:
    """NIS = y . solve(S, y) of one innovation (m,): the vector product of the one-estimate case."""
    return float(y @ np.linalg.solve(S, y))


def det_3x3(S: Floats) -> float:
    """det S of one 3x3 matrix by the rule of Sarrus (expanded along the first row)."""
    (a, b, c), (d, e, f), (g, h, i) = S.tolist()
    det: float = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    return det


_LOG_2PI = math.log(2.0 * math.pi)


def log_likelihood_3(nis_value: float, S: Floats) -> float:
    """ln N(y; 0, S) = -1/2 (NIS + ln det S + 3 ln 2 pi) of one 3-D innovation from its NIS (e.g. the one
    :func:`update_selection` returns), det S by :func:`det_3x3`; where cancellation leaves that ≤ 0 (an S whose
    entries span many orders of magnitude, e.g. a range sigma of 1e7 m beside 1e-3° angles), by LU
    (``slogdet``). ``LinAlgError`` when S is not positive definite (the callers' refusal of the update), never the
    ``ValueError`` of a logarithm of a negative number."""
    det = det_3x3(S)
    if det > 0.0:
        logdet = math.log(det)
    else:
        sign, logdet = np.linalg.slogdet(S)
        if not sign > 0.0:
            raise np.linalg.LinAlgError(f"innovation covariance not positive definite (det {det:.3g})")
    return -0.5 * (nis_value + logdet + 3.0 * _LOG_2PI)


def whitening_3x3(S: Floats) -> FloatArray:
    """W = L^-1 (lower triangular, 3x3) with sym(S) = L L^T, in closed form (scalar arithmetic).

    The off-diagonal elements of S enter as their means (s_ij + s_ji) / 2, so S need not be symmetric to the bit.
    Raises numpy.linalg.LinAlgError when S is not positive definite (a pivot <= 0 or NaN)."""
    (s00, s01, s02), (s10, s11, s12), (s20, s21, s22) = S.tolist()
    a01, a02, a12 = 0.5 * (s01 + s10), 0.5 * (s02 + s20), 0.5 * (s12 + s21)
    if not s00 > 0.0:
        raise np.linalg.LinAlgError("innovation covariance is not positive definite")
    l00 = math.sqrt(s00)
    l10, l20 = a01 / l00, a02 / l00
    d11 = s11 - l10 * l10
    if not d11 > 0.0:
        raise np.linalg.LinAlgError("innovation covariance is not positive definite")
    l11 = math.sqrt(d11)
    l21 = (a12 - l20 * l10) / l11
    d22 = s22 - l20 * l20 - l21 * l21
    if not d22 > 0.0:
        raise np.linalg.LinAlgError("innovation covariance is not positive definite")
    l22 = math.sqrt(d22)
    w00, w11, w22 = 1.0 / l00, 1.0 / l11, 1.0 / l22
    w10 = -l10 * w00 * w11
    w21 = -l21 * w11 * w22
    w20 = -(l20 * w00 + l21 * w10) * w22
    return np.array([[w00, 0.0, 0.0], [w10, w11, 0.0], [w20, w21, w22]])


@lru_cache(maxsize=16)
def _eye(n: int) -> FloatArray:
    eye = np.eye(n)
    eye.setflags(write=False)
    return eye


def update_selection(
    x: FloatArray, P: FloatArray, z: FloatArray, idx: slice, R: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """Joseph-form update of one estimate (x (n,), P (n, n)) with a 3-D measurement z of the components ``idx``
    (H = I[idx]) and noise R (3x3); returns (x, P, y, NIS) (module docstring).

    The products by H are indexing (``P[:, idx]`` = P H^T, exact), S = P[idx, idx] + R, the gain
    K = (P H^T W^T) W with W = L^-1 from :func:`whitening_3x3`, NIS = |W y|^2, and
    P <- sym((I - K H) P (I - K H)^T + K R K^T) with I - K H built by subtracting K from the columns ``idx`` of I.
    Equals :func:`update` (Joseph form) up to rounding. Raises numpy.linalg.LinAlgError if S is not positive
    definite."""
    pht = P[:, idx]
    w = whitening_3x3(pht[idx] + R)
    y = z - x[idx]
    e = w @ y
    nis_value = float(e @ e)
    k = (pht @ w.T) @ w
    x_new = x + k @ y
    i_kh = _eye(x.shape[0]).copy()
    i_kh[:, idx] -= k
    P_new = i_kh @ P @ i_kh.T + k @ R @ k.T
    return x_new, symmetrize(P_new), y, nis_value
