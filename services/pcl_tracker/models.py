"""Motion and measurement models (digest 003 §1.5, §1.6, §2.5).

Cartesian CV model on x_a = [x, y, z, v_x, v_y, v_z] with piecewise-constant white acceleration of variance
q (m^2/s^4); linear bistatic CV model (BKF, comparison variant) on x_b = [r_b, v_b, a, a_dot, e, e_dot].
All builders are batched over a vector of intervals tau (s).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .geometry import FloatArray

#: H = [I_3 0]: the converted plot observes the Cartesian position (digest §2.6)
H_POS = np.hstack([np.eye(3), np.zeros((3, 3))])
#: indices of z_b = [r_b, a, e, v_b] inside x_b = [r_b, v_b, a, a_dot, e, e_dot]
BKF_Z_FROM_XB = np.array([0, 2, 4, 1])
#: H_b selects z_b from x_b (4 x 6)
H_BKF = np.eye(6)[BKF_Z_FROM_XB]


def _taus(tau: ArrayLike) -> FloatArray:
    return np.atleast_1d(np.asarray(tau, dtype=np.float64))


def cv_transition(tau: ArrayLike) -> FloatArray:
    """F = [[I, tau I], [0, I]] for each tau, shape (B, 6, 6)."""
    t = _taus(tau)
    F = np.broadcast_to(np.eye(6), (t.size, 6, 6)).copy()
    idx = np.arange(3)
    F[:, idx, idx + 3] = t[:, None]
    return F


def cv_process_noise(tau: ArrayLike, q: float) -> FloatArray:
    """Q = q [[tau^4/4 I, tau^3/2 I], [tau^3/2 I, tau^2 I]] for each tau, shape (B, 6, 6)."""
    t = _taus(tau)
    Q = np.zeros((t.size, 6, 6))
    idx = np.arange(3)
    Q[:, idx, idx] = (q * t**4 / 4.0)[:, None]
    Q[:, idx, idx + 3] = (q * t**3 / 2.0)[:, None]
    Q[:, idx + 3, idx] = (q * t**3 / 2.0)[:, None]
    Q[:, idx + 3, idx + 3] = (q * t**2)[:, None]
    return Q


def bkf_transition(tau: ArrayLike) -> FloatArray:
    """F_b = diag(F_1, F_1, F_1) on [(r_b, v_b), (a, a_dot), (e, e_dot)], shape (B, 6, 6)."""
    t = _taus(tau)
    F = np.broadcast_to(np.eye(6), (t.size, 6, 6)).copy()
    for i in (0, 2, 4):
        F[:, i, i + 1] = t
    return F


def bkf_process_noise(tau: ArrayLike, q_r: float, q_ang: float) -> FloatArray:
    """Q_b = diag(q_r Q1u, q_ang Q1u, q_ang Q1u), Q1u = [[tau^4/4, tau^3/2], [tau^3/2, tau^2]]."""
    t = _taus(tau)
    Q = np.zeros((t.size, 6, 6))
    for i, q in ((0, q_r), (2, q_ang), (4, q_ang)):
        Q[:, i, i] = q * t**4 / 4.0
        Q[:, i, i + 1] = Q[:, i + 1, i] = q * t**3 / 2.0
        Q[:, i + 1, i + 1] = q * t**2
    return Q


def plot_covariance(sigmas: ArrayLike) -> FloatArray:
    """R_b = diag(sigma^2) for sigmas (B, k) in the units of the plot (m, rad, rad, m/s)."""
    s = np.asarray(sigmas, dtype=np.float64)
    R = np.zeros((*s.shape, s.shape[-1]))
    idx = np.arange(s.shape[-1])
    R[..., idx, idx] = s**2
    return R
