"""The second-order Kalman filter of eq. (3): predict with B and M, update with the converted plot.

The update uses the Joseph form and symmetrises the covariance (§5.6 "covariance hygiene"); the innovation
covariance enters through a linear solve, never an explicit inverse.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy.linalg.lapack import dpotrf

from .geometry import F64
from .models import POS, process_noise, transition

_I9 = np.eye(9)


@lru_cache(maxsize=256)
def _model(dt_s: float, d_a: tuple[float, float, float]) -> tuple[F64, F64]:
    b = transition(dt_s)
    m = process_noise(dt_s, d_a)
    b.setflags(write=False)
    m.setflags(write=False)
    return b, m


def predict(x: F64, p: F64, dt_s: float, d_a: tuple[float, float, float], symmetrise: bool = True) -> tuple[F64, F64]:
    """alpha~ = B alpha, R~ = B R B^T + M over dt_s (any sign; the actual dt, never the nominal T).

    ``symmetrise=False`` skips the final symmetrisation when an update (which symmetrises) follows at once.
    """
    b, m = _model(float(dt_s), d_a)
    x_pred = b @ x
    p_pred = b @ p @ b.T + m
    return x_pred, (0.5 * (p_pred + p_pred.T) if symmetrise else p_pred)


def innovation(x_pred: F64, p_pred: F64, z: F64, rz: F64) -> tuple[F64, F64]:
    """nu = z - H alpha~ and its covariance S = H R~ H^T + R_z."""
    nu = z - x_pred[POS]
    s = p_pred[POS, POS] + rz
    return nu, 0.5 * (s + s.T)


def update(x_pred: F64, p_pred: F64, z: F64, rz: F64) -> tuple[F64, F64, float]:
    """Kalman update with a position measurement (eq. 3, Joseph form); returns (alpha, R_alpha, NIS). The state may
    extend the 9-state of eq. (3) by components after the ninth (the IMM's turn rate); H picks the positions.

    S = H R~ H^T + R_z is factorised S = L L^T (Cholesky); K = R~ H^T L^-T L^-1 and NIS = |L^-1 nu|^2.
    Raises numpy.linalg.LinAlgError if S is not positive definite.
    """
    pht = p_pred[:, POS]  # R~ H^T (9x3)
    (s00, s01, s02), (s10, s11, s12), (s20, s21, s22) = (pht[POS] + rz).tolist()
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
    w00, w11, w22 = 1.0 / l00, 1.0 / l11, 1.0 / l22  # W = L^-1 (lower triangular)
    w10 = -l10 * w00 * w11
    w21 = -l21 * w11 * w22
    w20 = -(l20 * w00 + l21 * w10) * w22
    w = np.array([[w00, 0.0, 0.0], [w10, w11, 0.0], [w20, w21, w22]])
    nu = z - x_pred[POS]
    e = w @ nu
    nis = float(e @ e)
    k = (pht @ w.T) @ w
    x = x_pred + k @ nu
    i_kh = _I9.copy() if x_pred.shape[0] == 9 else np.eye(x_pred.shape[0])
    i_kh[:, POS] -= k
    p = i_kh @ p_pred @ i_kh.T + k @ rz @ k.T  # Joseph form
    return x, 0.5 * (p + p.T), nis


def nis_of(x_pred: F64, p_pred: F64, z: F64, rz: F64) -> float:
    """Normalised innovation squared nu^T S^-1 nu of a plot against a predicted state."""
    nu, s = innovation(x_pred, p_pred, z, rz)
    return float(nu @ np.linalg.solve(s, nu))


def is_positive_definite(p: F64) -> bool:
    """True if the covariance is finite and its Cholesky factorisation (LAPACK dpotrf) succeeds."""
    if not np.isfinite(p).all():
        return False
    return int(dpotrf(p, lower=1, clean=0)[1]) == 0
