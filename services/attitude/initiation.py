"""Finite-sample filter (FSF) start, eq. (2) [RECON], and the raw sliding-window baseline (§2.6).

alpha_n = R_n H_n^T Q_theta theta_n,  Q_n = R_n^-1 = H_n^T Q_theta H_n (R_n: the state covariance, P in the code and
the toolkit's notation, see filter.py), with the reference time at the latest
plot (tau_i = t_i - t_n) [CHOICE: the only one that lets the KF continue]. With n = 3 plots and 9 states H_n is
square and the FSF is an exact quadratic interpolation through the three converted plots.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from shared.filters.covariance import symmetrize

from .geometry import F64


def fsf_design(taus_s: Sequence[float] | F64) -> F64:
    """H_n (3n x 9): block row of plot i, axis c is [1, tau_i, tau_i^2/2] placed in axis block c."""
    taus = np.asarray(taus_s, dtype=np.float64)
    n = taus.size
    h = np.zeros((3 * n, 9))
    for i, tau in enumerate(taus):
        row = (1.0, float(tau), 0.5 * float(tau) * float(tau))
        for c in range(3):
            h[3 * i + c, 3 * c : 3 * c + 3] = row
    return h


def fsf_estimate(taus_s: Sequence[float] | F64, zs: F64, rs: F64) -> tuple[F64, F64]:
    """Weighted least-squares FSF of eq. (2).

    Args:
        taus_s: plot times relative to the reference (latest) time, s, shape (n,).
        zs: converted positions theta_i,xyz, m, shape (n, 3).
        rs: their covariances R_i, m^2, shape (n, 3, 3).

    Returns:
        (alpha_n, P_n): the 9-state estimate at the reference time and its covariance R_n of eq. (2)
        (symmetrised).
    """
    h = fsf_design(taus_s)
    n = h.shape[0] // 3
    # whiten each plot with its Cholesky factor: Q_theta = W^T W, W = blkdiag(L_i^-1)
    a = np.empty_like(h)
    b = np.empty(3 * n)
    for i in range(n):
        lower = np.linalg.cholesky(rs[i])
        a[3 * i : 3 * i + 3] = np.linalg.solve(lower, h[3 * i : 3 * i + 3])
        b[3 * i : 3 * i + 3] = np.linalg.solve(lower, zs[i])
    # least squares through QR: alpha = argmin |A alpha - b|, P_n = (A^T A)^-1 = U^-1 U^-T
    q, u = np.linalg.qr(a, mode="reduced")
    alpha = np.linalg.solve(u, q.T @ b)
    u_inv = np.linalg.solve(u, np.eye(9))
    return alpha, symmetrize(u_inv @ u_inv.T)


def fsf_condition(taus_s: Sequence[float] | F64) -> float:
    """cond(H_n), used to refuse an FSF start from plots too close in time (§5.6)."""
    return float(np.linalg.cond(fsf_design(taus_s)))


def quadratic_state(taus_s: Sequence[float], zs: Sequence[Sequence[float]]) -> list[float]:
    """Exact quadratic interpolation through three plots (the 3-point FSF without weights): alpha at tau = 0.

    ``taus_s`` are the three plot times relative to the reference time (normally the last is 0), ``zs`` the
    converted positions (x, y, z) in m. This is the raw (single-look) baseline of §2.6, used in a sliding window.
    Lagrange basis: p = sum L_i(0) z_i, V = sum L_i'(0) z_i, a = sum L_i''(0) z_i. Returns [x Vx ax y Vy ay z Vz az].
    """
    t0, t1, t2 = (float(t) for t in taus_s)
    d0 = (t0 - t1) * (t0 - t2)
    d1 = (t1 - t0) * (t1 - t2)
    d2 = (t2 - t0) * (t2 - t1)
    wp = (t1 * t2 / d0, t0 * t2 / d1, t0 * t1 / d2)
    wv = (-(t1 + t2) / d0, -(t0 + t2) / d1, -(t0 + t1) / d2)
    wa = (2.0 / d0, 2.0 / d1, 2.0 / d2)
    z0, z1, z2 = zs
    out: list[float] = []
    for c in range(3):
        a, b, e = float(z0[c]), float(z1[c]), float(z2[c])
        out += [wp[0] * a + wp[1] * b + wp[2] * e, wv[0] * a + wv[1] * b + wv[2] * e, wa[0] * a + wa[1] * b + wa[2] * e]
    return out
