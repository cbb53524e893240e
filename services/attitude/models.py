"""Motion and measurement models of the second-order (constant-acceleration) Kalman filter, eq. (3).

State ordering is axis-blocked (§2.1): alpha = [x Vx ax  y Vy ay  z Vz az] in m, m/s, m/s^2.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy.linalg import expm

from shared.filters.covariance import symmetrize

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
    return symmetrize(m)


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
    return f, symmetrize(q)


#: longest step of one Van Loan exponential in :func:`singer_axis`, s
SINGER_SUBSTEP_S = 10.0


def block_diagonal(axis: F64) -> F64:
    """blkdiag(m, m, m) (9x9) of a 3x3 per-axis matrix, in the axis-blocked state order."""
    out = np.zeros((9, 9))
    for c in range(3):
        out[3 * c : 3 * c + 3, 3 * c : 3 * c + 3] = axis
    return out


# ------------------------------------------------------------------------------------------------ coordinated turn
#: the turn-rate state of the coordinated-turn (CT) model: alpha' = [x Vx ax y Vy ay z Vz az omega] (10-state)
OMEGA = 9
#: the horizontal components [x Vx ax z Vz az] (N and E axes) and the vertical ones [y Vy ay] of the state
HORIZ = (0, 1, 2, 6, 7, 8)
VERT = (3, 4, 5)
_H7 = (*HORIZ, OMEGA)
_HORIZ_A = np.array(HORIZ)
_VERT_A = np.array(VERT)
_HIX = np.ix_(HORIZ, HORIZ)
_VIX = np.ix_(VERT, VERT)
_H7IX = np.ix_(_H7, _H7)
#: d A / d omega of the horizontal block (see :func:`ct_horizontal`), with the 1/tau terms added there
_DA_ROT = np.zeros((6, 6))
_DA_ROT[2, 5] = -1.0  # d(ax)/dt = -omega az ...
_DA_ROT[5, 2] = 1.0  # d(az)/dt = +omega ax ...
_DA_PULL = np.zeros((6, 6))
_DA_PULL[2, 4] = -1.0  # ... - (omega / tau) Vz
_DA_PULL[5, 1] = 1.0  # ... + (omega / tau) Vx


def ct_horizontal(omega: float, tau_s: float) -> tuple[F64, F64]:
    """(A, dA/domega) (6x6) of the horizontal block [x Vx ax z Vz az] of the nearly coordinated turn model:

        d(x)/dt = Vx,  d(Vx)/dt = ax,  d(ax)/dt = -omega az - (ax + omega Vz) / tau + w_x
        d(z)/dt = Vz,  d(Vz)/dt = az,  d(az)/dt = +omega ax - (az - omega Vx) / tau + w_z

    i.e. a_h = omega x V_h + b with the deviation b from the coordinated-turn acceleration a Singer process
    (d(b)/dt = -b / tau + w): d(a)/dt = omega x a + d(b)/dt for a constant turn rate omega (rad/s, positive
    clockwise seen from above: heading psi = atan2(Vz, Vx) grows). omega = 0 is the Singer model of each axis."""
    a = np.zeros((6, 6))
    for base in (0, 3):
        a[base, base + 1] = 1.0
        a[base + 1, base + 2] = 1.0
        a[base + 2, base + 2] = -1.0 / tau_s
    da = _DA_ROT + _DA_PULL / tau_s
    return a + omega * da, da


def ct_step(x: F64, dt_s: float, sigma_accel_mps2: float, tau_s: float, q_omega: float) -> tuple[F64, F64, F64]:
    """One EKF prediction step of the nearly coordinated turn (CT) model over dt_s on the 10-state
    alpha' = [x Vx ax y Vy ay z Vz az omega]: (predicted state, Jacobian F = d(state')/d(state) (10x10), Q (10x10)).

    * horizontal [x Vx ax z Vz az]: :func:`ct_horizontal` at the state's omega, exact for a constant omega
      (Phi = expm(A dt)); the Jacobian's omega column is the Frechet derivative (dPhi/domega) h, the upper-right
      block of expm([[A, dA], [0, A]] dt) (Van Loan 1978), so F is the exact derivative of the discrete map;
    * vertical [y Vy ay]: the Singer model (:func:`singer_axis`) with the same sigma_a and tau;
    * omega: a random walk, E[d(omega) d(omega)] = q_omega dt (rad^2/s^2).

    Q: :func:`ct_process_noise`. With omega = 0 and q_omega = 0 this is the Singer model of every axis
    (blkdiag(singer_axis)) plus a constant omega. The default preset predicts by :func:`ct_predict` instead (the
    EKF's linearisation in omega is poor at a turn's start); this step is its reference and its option."""
    omega = float(x[OMEGA])
    h = x[_HORIZ_A]
    a, da = ct_horizontal(omega, tau_s)
    big = np.zeros((12, 12))
    big[:6, :6] = a
    big[:6, 6:] = da
    big[6:, 6:] = a
    e = expm(big * dt_s)
    phi, dphi = e[:6, :6], e[:6, 6:]
    fv = _singer_transition(dt_s, sigma_accel_mps2, tau_s)
    f = np.zeros((10, 10))
    f[_HIX] = phi
    f[_HORIZ_A, OMEGA] = dphi @ h
    f[_VIX] = fv
    f[OMEGA, OMEGA] = 1.0
    xp = np.empty(10)
    xp[_HORIZ_A] = phi @ h
    xp[_VERT_A] = fv @ x[_VERT_A]
    xp[OMEGA] = omega
    return xp, f, ct_process_noise(x, dt_s, sigma_accel_mps2, tau_s, q_omega)


def ct_process_noise(x: F64, dt_s: float, sigma_accel_mps2: float, tau_s: float, q_omega: float) -> F64:
    """Q (10x10) of the CT model over |dt_s| at the state x: the deviation b has the Singer density
    2 sigma_a^2 / tau on each horizontal axis, omega the density q_omega; Q of the horizontal block and omega is
    Van Loan's integral for the system linearised at x (omega and the horizontal state frozen over the step:
    d(h)/dt = A h + (dA h) (omega - omega0), d(omega)/dt = w), chained over sub-steps of at most SINGER_SUBSTEP_S;
    the vertical block is the Singer model's Q. Symmetric positive semi-definite by construction."""
    a, da = ct_horizontal(float(x[OMEGA]), tau_s)
    dt = abs(dt_s)
    n = max(1, math.ceil(dt / SINGER_SUBSTEP_S))
    step = dt / n
    # omega is scaled by k (omega' = omega / k) so that its column of A7 is O(1): a well-scaled exponential
    coupling = da @ x[_HORIZ_A]
    k = max(float(np.abs(coupling).max()), 1.0)
    van_loan = np.zeros((14, 14))
    van_loan[:6, :6] = -a
    van_loan[:6, 6] = -coupling / k
    van_loan[2, 9] = van_loan[5, 12] = 2.0 * sigma_accel_mps2 * sigma_accel_mps2 / tau_s
    van_loan[6, 13] = q_omega * k * k
    van_loan[7:13, 7:13] = a.T
    van_loan[13, 7:13] = coupling / k
    ev = expm(van_loan * step)
    f7 = ev[7:, 7:].T
    q7 = f7 @ ev[:7, 7:]
    q = q7
    for _ in range(n - 1):
        q = f7 @ q @ f7.T + q7
    q[6, :] /= k  # back from omega' to omega: Q = D Q' D, D = diag(1, .., 1, 1 / k)
    q[:, 6] /= k
    out = np.zeros((10, 10))
    out[_H7IX] = symmetrize(q)
    out[_VIX] = _singer_cached(dt, sigma_accel_mps2, tau_s)[1]
    return out


def _singer_transition(dt_s: float, sigma_accel_mps2: float, tau_s: float) -> F64:
    """The vertical Singer transition over dt_s (the inverse of the forward one for dt_s < 0)."""
    f = _singer_cached(abs(dt_s), sigma_accel_mps2, tau_s)[0]
    return f if dt_s >= 0.0 else np.asarray(np.linalg.inv(f), dtype=np.float64)


@lru_cache(maxsize=1024)
def _singer_cached(dt_s: float, sigma_accel_mps2: float, tau_s: float) -> tuple[F64, F64]:
    f, q = singer_axis(dt_s, sigma_accel_mps2, tau_s)
    f.setflags(write=False)
    q.setflags(write=False)
    return f, q


def turn_rate(x: F64, v_floor_mps: float = 1.0) -> tuple[float, F64]:
    """The turn rate psi_dot = (Vx az - Vz ax) / V_h^2 (rad/s) of a 9- or 10-state and its gradient with respect to
    the first 9 components (9,): the omega that a CA or Singer model's state implies (V_h floored at v_floor_mps)."""
    vx, ax, vz, az = float(x[1]), float(x[2]), float(x[7]), float(x[8])
    vh2 = max(vx * vx + vz * vz, v_floor_mps * v_floor_mps)
    w = (vx * az - vz * ax) / vh2
    g = np.zeros(9)
    g[1] = (az - 2.0 * vx * w) / vh2
    g[2] = -vz / vh2
    g[7] = (-ax - 2.0 * vz * w) / vh2
    g[8] = vx / vh2
    return w, g


#: Gauss-Hermite nodes and weights of the standard normal (5 points: exact for polynomials up to degree 9)
_GH_X, _GH_W = np.polynomial.hermite_e.hermegauss(5)
_GH_W = _GH_W / _GH_W.sum()


def ct_transitions(omegas: F64, dt_s: float, tau_s: float) -> F64:
    """Phi(omega) = expm(A(omega) dt) (K, 6, 6) of the horizontal block (:func:`ct_horizontal`) for K turn rates,
    in closed form. With u = (x + i z, Vx + i Vz, ax + i az) the block is the complex 3x3 system u' = C u,
    C = [[0, 1, 0], [0, 0, 1], [0, -p q, p + q]], p = i omega, q = -1 / tau (eigenvalues 0, p, q), and Putzer's
    (Newton's divided-difference) form gives expm(C t) = I + f[0, p] C + f[0, p, q] C (C - p I) with the divided
    differences of exp(lambda t): f[0, p] = (e^(pt) - 1) / p (written with sinc: no cancellation as omega -> 0),
    f[p, q] = (e^(qt) - e^(pt)) / (q - p), f[0, p, q] = (f[p, q] - f[0, p]) / q. Real form
    [[Re, -Im], [Im, Re]] in the order [x Vx ax z Vz az]. Falls back to scipy's expm when |q dt| < 1e-3 (a tau so
    long that the last divided difference would cancel)."""
    om = np.asarray(omegas, dtype=np.float64)
    k = om.size
    qt = -dt_s / tau_s
    if abs(qt) < 1e-3:
        return np.stack([expm(ct_horizontal(float(w), tau_s)[0] * dt_s) for w in om])
    q = -1.0 / tau_s
    p = 1j * om
    th = om * dt_s
    # f[0, p] = (e^(i th) - 1) / (i omega) = t (sin th / th + i (th / 2) (sin(th/2) / (th/2))^2)
    half = np.sinc(th / (2.0 * np.pi))
    f0p = dt_s * (np.sinc(th / np.pi) + 0.5j * th * half * half)
    fpq = (math.exp(qt) - np.exp(1j * th)) / (q - p)
    f0pq = (fpq - f0p) / q
    c = np.zeros((k, 3, 3), dtype=np.complex128)
    c[:, 0, 1] = 1.0
    c[:, 1, 2] = 1.0
    c[:, 2, 1] = -p * q
    c[:, 2, 2] = p + q
    c2 = c @ c
    m = f0p[:, None, None] * c + f0pq[:, None, None] * (c2 - p[:, None, None] * c)
    m[:, 0, 0] += 1.0
    m[:, 1, 1] += 1.0
    m[:, 2, 2] += 1.0
    out = np.empty((k, 6, 6))
    out[:, :3, :3] = m.real
    out[:, :3, 3:] = -m.imag
    out[:, 3:, :3] = m.imag
    out[:, 3:, 3:] = m.real
    return out


def ct_quadrature_nodes(
    x: F64, p: F64, dt_s: float, sigma_accel_mps2: float, tau_s: float
) -> tuple[F64, F64, F64, F64, F64]:
    """The Gauss-Hermite nodes over the turn rate of :func:`ct_predict` (and of the fixed-lag smoother's
    cross-covariances, :func:`ct_cross_covariance`): (dev (K,): omega_k - omega_bar, weights (K,), k (9,): the
    regression P_a,omega / P_omega,omega of the 9-state on omega, C (9x9): its covariance given omega, Phi (K, 9, 9):
    the transitions at the nodes). A turn rate known to 1e-7 rad/s is one node with no regression."""
    omega = float(x[OMEGA])
    s2 = float(p[OMEGA, OMEGA])
    if not s2 > 1e-14:
        dev, weights = np.zeros(1), np.ones(1)
        k = np.zeros(9)
        c = p[:9, :9]
    else:
        dev, weights = math.sqrt(s2) * _GH_X, _GH_W
        k = p[:9, OMEGA] / s2
        c = p[:9, :9] - np.outer(k, p[OMEGA, :9])
    nk = dev.size
    phi = np.zeros((nk, 9, 9))
    phi[:, _HORIZ_A[:, None], _HORIZ_A[None, :]] = ct_transitions(omega + dev, dt_s, tau_s)
    phi[:, _VERT_A[:, None], _VERT_A[None, :]] = _singer_transition(dt_s, sigma_accel_mps2, tau_s)
    return dev, weights, k, c, phi


def ct_cross_covariance(x: F64, p: F64, b: F64, dt_s: float, sigma_accel_mps2: float, tau_s: float) -> F64:
    """cov(alpha~, y) (10 x K) of the CT model's predicted 10-state alpha~ with any other Gaussian variables y
    (the fixed-lag smoother's lagged states), given B = cov(alpha, y) (10 x K) before the step. With y | omega
    Gaussian of mean y_bar + k_y (omega - omega_bar) (k_y = B[omega] / P_omega,omega) and conditional covariance
    with the 9-state C_ay = B[:9] - k B[omega], E[Phi(omega) alpha (y - y_bar)^T] over omega's Gaussian is

        sum_n w_n Phi_n [C_ay + m_n k_y^T dev_n],    m_n = alpha_bar + k dev_n

    by the nodes of :func:`ct_predict` (exact for the same polynomial degree); the turn rate's own row is B[omega]
    (a random walk; the process noise is independent of y). For a known omega this is Phi(omega) B[:9]."""
    dev, weights, k, _, phi = ct_quadrature_nodes(x, p, dt_s, sigma_accel_mps2, tau_s)
    s2 = float(p[OMEGA, OMEGA])
    b_om = b[OMEGA]
    out = np.empty_like(b)
    out[OMEGA] = b_om
    if dev.size == 1:
        out[:9] = phi[0] @ b[:9]
        return out
    c_ay = b[:9] - np.outer(k, b_om)
    k_y = b_om / s2
    m = x[:9] + dev[:, None] * k  # (K nodes, 9)
    acc = np.zeros_like(c_ay)
    for n in range(dev.size):
        acc += weights[n] * (phi[n] @ (c_ay + dev[n] * np.outer(m[n], k_y)))
    out[:9] = acc
    return out


def ct_predict(x: F64, p: F64, dt_s: float, sigma_accel_mps2: float, tau_s: float, q_omega: float) -> tuple[F64, F64]:
    """The CT model's prediction of (x, P) (10-state) by Gauss-Hermite quadrature over the turn rate:

    given omega the model is linear (:func:`ct_horizontal`, exact transition Phi(omega) = expm(A(omega) dt),
    :func:`ct_transitions`), so with alpha | omega ~ N(m + k (omega - omega_bar), C) (k = P_a,omega / P_omega,omega,
    C the conditional covariance) the predicted moments are integrals over omega's Gaussian of Phi(omega) m(omega)
    and Phi(omega) C Phi(omega)^T + Phi(omega) m(omega) m(omega)^T, which the 5-point Gauss-Hermite rule computes
    exactly for a Phi polynomial in omega up to degree 4 (a UKF-type step in the one nonlinear direction; the EKF,
    :func:`ct_step`, linearises Phi in omega, which goes wrong when omega is uncertain to several deg/s at the start
    of a turn: a 0.1 rad/s spread is 30 deg of heading over one 5 s scan). Q: :func:`ct_process_noise` at the
    mean."""
    omega = float(x[OMEGA])
    s2 = float(p[OMEGA, OMEGA])
    q = ct_process_noise(x, dt_s, sigma_accel_mps2, tau_s, q_omega)
    dev, weights, k, c, phi = ct_quadrature_nodes(x, p, dt_s, sigma_accel_mps2, tau_s)
    m = np.matmul(phi, (x[:9] + dev[:, None] * k)[:, :, None])[:, :, 0]
    mean = weights @ m
    wm = m * weights[:, None]
    second = np.tensordot((phi * weights[:, None, None]) @ c, phi, axes=([0, 2], [0, 2])) + wm.T @ m
    xp = np.empty(10)
    xp[:9] = mean
    xp[OMEGA] = omega
    pp = np.empty((10, 10))
    pp[:9, :9] = second - np.outer(mean, mean)
    cross = (weights * dev) @ m
    pp[:9, OMEGA] = cross
    pp[OMEGA, :9] = cross
    pp[OMEGA, OMEGA] = s2
    pp += q
    return xp, symmetrize(pp)
