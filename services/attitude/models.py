"""Motion and measurement models of the second-order (constant-acceleration) Kalman filter, eq. (3).

State ordering is axis-blocked (§2.1): alpha = [x Vx ax  y Vy ay  z Vz az] in m, m/s, m/s^2.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm

from .geometry import F64

#: position, velocity and acceleration components of the axis-blocked state (basic slices: views, no copies)
POS = slice(0, 9, 3)
VEL = slice(1, 9, 3)
ACC = slice(2, 9, 3)

#: H (3x9): picks the positions (ones at (0,0), (1,3), (2,6))
H_POS: F64 = np.zeros((3, 9))
H_POS[0, 0] = H_POS[1, 3] = H_POS[2, 6] = 1.0


def transition_axis(dt_s: float) -> F64:
    """Per-coordinate transition b(dt) = [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]]."""
    return np.array([[1.0, dt_s, 0.5 * dt_s * dt_s], [0.0, 1.0, dt_s], [0.0, 0.0, 1.0]])


def transition(dt_s: float) -> F64:
    """B(dt) = blkdiag(b, b, b) (9x9)."""
    b = transition_axis(dt_s)
    out = np.zeros((9, 9))
    for c in range(3):
        out[3 * c : 3 * c + 3, 3 * c : 3 * c + 3] = b
    return out


def jerk_input(dt_s: float) -> F64:
    """S (3x9): maps a jerk held constant over one step (m/s^3) into the state increment."""
    g = np.array([dt_s**3 / 6.0, dt_s**2 / 2.0, dt_s])
    s = np.zeros((3, 9))
    for c in range(3):
        s[c, 3 * c : 3 * c + 3] = g
    return s


def process_noise(dt_s: float, d_a: tuple[float, float, float]) -> F64:
    """Random-manoeuvre matrix M = S^T D_a S (9x9) [RECON of the OCR's "M=S'SD"]; D_a = diag(D_x, D_y, D_z)."""
    s = jerk_input(dt_s)
    m = (s.T * np.asarray(d_a, dtype=np.float64)) @ s
    return 0.5 * (m + m.T)


def singer_axis(dt_s: float, sigma_accel_mps2: float, tau_s: float) -> tuple[F64, F64]:
    """Singer model of one axis over dt: the acceleration is a first-order Markov process (mean-reverting),

        d(a)/dt = -a / tau + w,    E[w(t) w(s)] = q delta(t - s),    q = 2 sigma_a^2 / tau,

    so its stationary standard deviation is sigma_a. Returns (F, Q) (3x3) of [p, v, a]: F = expm(A h) and
    Q = int_0^h expm(A s) G q G^T expm(A s)^T ds by Van Loan's method (one 6x6 matrix exponential) for steps
    h <= SINGER_SUBSTEP_S, chained (F <- F_h F, Q <- F_h Q F_h^T + Q_h) over longer dt, where the exponential of
    Van Loan's block matrix would lose Q to cancellation. As tau -> infinity with q fixed this is the
    constant-acceleration model driven by white jerk.
    """
    n = max(1, math.ceil(abs(dt_s) / SINGER_SUBSTEP_S))
    h = dt_s / n
    a = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0 / tau_s]])
    gqg = np.zeros((3, 3))
    gqg[2, 2] = 2.0 * sigma_accel_mps2 * sigma_accel_mps2 / tau_s
    van_loan = np.zeros((6, 6))
    van_loan[:3, :3] = -a
    van_loan[:3, 3:] = gqg
    van_loan[3:, 3:] = a.T
    e = expm(van_loan * h)
    f_h = e[3:, 3:].T
    q_h = f_h @ e[:3, 3:]
    f, q = f_h, q_h
    for _ in range(n - 1):
        f = f_h @ f
        q = f_h @ q @ f_h.T + q_h
    return f, 0.5 * (q + q.T)


#: longest step of one Van Loan exponential in :func:`singer_axis`, s
SINGER_SUBSTEP_S = 10.0


def block_diagonal(axis: F64) -> F64:
    """blkdiag(m, m, m) (9x9) of a 3x3 per-axis matrix, in the axis-blocked state order."""
    out = np.zeros((9, 9))
    for c in range(3):
        out[3 * c : 3 * c + 3, 3 * c : 3 * c + 3] = axis
    return out
