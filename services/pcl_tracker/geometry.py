"""Bistatic geometry of one receiver–illuminator pair (digest 003, §1).

Frame: local ENU with the receiver at the origin (X east, Y north, Z up). Azimuth ``alpha`` is measured
clockwise from north (``atan2(x, y)``), elevation ``eps`` from the horizontal plane. All angles are in
radians inside the core; the transmitter position ``tx`` is in metres.

Component orders (digest §2.1), kept distinct on purpose:

* Cartesian state ``x_a = [x, y, z, v_x, v_y, v_z]`` (m, m/s)
* bistatic measurement ``z_b = [r_b, alpha, eps, v_b]`` (m, rad, rad, m/s)
* bistatic state ``x_b = [r_b, v_b, alpha, alpha_dot, eps, eps_dot]`` (m, m/s, rad, rad/s, rad, rad/s)

Every function accepts arrays with any number of leading (batch) dimensions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: index of the azimuth in z_b (used to wrap UT outputs and innovations)
AZ_INDEX = 1
#: [D] (digest §5.6) a UT sigma point with r_b < 0 or D <= D_MIN is clamped to r_b = RB_CLAMP_M
D_MIN = 1e-6
RB_CLAMP_M = 1e-3


def baseline(tx: ArrayLike) -> float:
    """Baseline L = |t| (m)."""
    return float(np.linalg.norm(np.asarray(tx, dtype=np.float64)))


def u_los(alpha: ArrayLike, eps: ArrayLike) -> FloatArray:
    """Unit line-of-sight vector (sin a cos e, cos a cos e, sin e), shape (..., 3)."""
    a = np.asarray(alpha, dtype=np.float64)
    e = np.asarray(eps, dtype=np.float64)
    ce = np.cos(e)
    return np.stack([np.sin(a) * ce, np.cos(a) * ce, np.sin(e) * np.ones_like(a)], axis=-1)


def h_b(x_a: ArrayLike, tx: ArrayLike) -> FloatArray:
    """Forward transform (digest §1.3): Cartesian state (..., 6) -> z_b = [r_b, alpha, eps, v_b] (..., 4)."""
    x = np.asarray(x_a, dtype=np.float64)
    t = np.asarray(tx, dtype=np.float64)
    px, py, pz = x[..., 0], x[..., 1], x[..., 2]
    vx, vy, vz = x[..., 3], x[..., 4], x[..., 5]
    dx, dy, dz = px - t[0], py - t[1], pz - t[2]
    R_r = np.sqrt(px * px + py * py + pz * pz)
    R_t = np.sqrt(dx * dx + dy * dy + dz * dz)
    R_r_safe = np.maximum(R_r, 1e-12)
    R_t_safe = np.maximum(R_t, 1e-12)
    L = np.sqrt(t @ t)
    r_b = R_r + R_t - L
    alpha = np.arctan2(px, py)
    eps = np.arcsin(np.clip(pz / R_r_safe, -1.0, 1.0))
    v_b = (px * vx + py * vy + pz * vz) / R_r_safe + (dx * vx + dy * vy + dz * vz) / R_t_safe
    return np.stack([r_b, alpha, eps, v_b], axis=-1)


def h_b_position(p: ArrayLike, tx: ArrayLike) -> FloatArray:
    """Position part of h_b: (..., 3) -> [r_b, alpha, eps] (..., 3)."""
    pos = np.asarray(p, dtype=np.float64)
    x = np.concatenate([pos, np.zeros_like(pos)], axis=-1)
    return h_b(x, tx)[..., :3]


def _clamped_range(
    r_b: FloatArray, u: FloatArray, t: FloatArray, L: float
) -> tuple[FloatArray, FloatArray, BoolArray, BoolArray]:
    """Apply the sigma-point guard of digest §5.6: r_b < 0 or D <= D_MIN -> r_b = RB_CLAMP_M."""
    S = r_b + L
    D = 2.0 * (S - u @ t)
    clamp = (r_b < 0.0) | (D <= D_MIN)
    if np.any(clamp):
        r_b = np.where(clamp, RB_CLAMP_M, r_b)
        S = r_b + L
        D = 2.0 * (S - u @ t)
    valid = D > D_MIN
    return r_b, D, clamp, valid


def h_a3(y: ArrayLike, tx: ArrayLike) -> tuple[FloatArray, BoolArray, BoolArray]:
    """Inverse transform h_a^(3) (digest §1.4): [r_b, alpha, eps] (..., 3) -> position (..., 3).

    Returns ``(p, clamped, valid)``: ``clamped`` marks points whose r_b was clamped by the §5.6 guard,
    ``valid`` is False where D is still <= 1e-6 after clamping (the caller must not use that point).
    """
    yy = np.asarray(y, dtype=np.float64)
    t = np.asarray(tx, dtype=np.float64)
    L = float(np.sqrt(t @ t))
    u = u_los(yy[..., 1], yy[..., 2])
    r_b, D, clamped, valid = _clamped_range(yy[..., 0], u, t, L)
    S = r_b + L
    R_r = (S * S - L * L) / np.where(valid, D, 1.0)
    return R_r[..., None] * u, clamped, valid


def h_a6(x_b: ArrayLike, tx: ArrayLike) -> tuple[FloatArray, BoolArray, BoolArray]:
    """Inverse transform h_a^(6): x_b = [r_b, v_b, alpha, alpha_dot, eps, eps_dot] -> x_a (..., 6).

    Velocity by the quotient rule written with du/dt (digest §6); identical to :func:`h_a6_quotient`.
    Returns ``(x_a, clamped, valid)`` as :func:`h_a3`.
    """
    xb = np.asarray(x_b, dtype=np.float64)
    t = np.asarray(tx, dtype=np.float64)
    L = float(np.sqrt(t @ t))
    v_b, az, azd, el, eld = xb[..., 1], xb[..., 2], xb[..., 3], xb[..., 4], xb[..., 5]
    u = u_los(az, el)
    r_b, D, clamped, valid = _clamped_range(xb[..., 0], u, t, L)
    ca, sa, ce, se = np.cos(az), np.sin(az), np.cos(el), np.sin(el)
    du = azd[..., None] * np.stack([ca * ce, -sa * ce, np.zeros_like(az)], axis=-1) + eld[..., None] * np.stack(
        [-sa * se, -ca * se, ce], axis=-1
    )
    S = r_b + L
    A = S * S - L * L
    Ds = np.where(valid, D, 1.0)
    dD = 2.0 * (v_b - du @ t)
    N = A[..., None] * u
    dN = (2.0 * v_b * S)[..., None] * u + A[..., None] * du
    pos = N / Ds[..., None]
    vel = (dN * Ds[..., None] - dD[..., None] * N) / (Ds * Ds)[..., None]
    return np.concatenate([pos, vel], axis=-1), clamped, valid


def h_a6_quotient(x_b: ArrayLike, tx: ArrayLike) -> FloatArray:
    """h_a^(6) written exactly as the paper's quotient rule (digest §1.4, N_x..N_z, D and their rates)."""
    xb = np.asarray(x_b, dtype=np.float64)
    xt, yt, zt = (float(c) for c in np.asarray(tx, dtype=np.float64))
    L = float(np.sqrt(xt * xt + yt * yt + zt * zt))
    r_b, v_b, a, ad, e, ed = (xb[..., i] for i in range(6))
    S = r_b + L
    A = S * S - L * L
    sa, ca, se, ce = np.sin(a), np.cos(a), np.sin(e), np.cos(e)
    Nx, Ny, Nz = A * sa * ce, A * ca * ce, A * se
    D = 2.0 * (S - xt * sa * ce - yt * ca * ce - zt * se)
    dNx = 2 * v_b * S * sa * ce + A * (ad * ca * ce - ed * sa * se)
    dNy = 2 * v_b * S * ca * ce - A * (ad * sa * ce + ed * ca * se)
    dNz = 2 * v_b * S * se + A * ed * ce
    dD = 2.0 * (v_b - xt * (ad * ca * ce - ed * sa * se) + yt * (ad * sa * ce + ed * ca * se) - zt * ed * ce)
    return np.stack(
        [Nx / D, Ny / D, Nz / D, (dNx * D - dD * Nx) / D**2, (dNy * D - dD * Ny) / D**2, (dNz * D - dD * Nz) / D**2],
        axis=-1,
    )


def angle_rates(x_a: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Azimuth and elevation rates (rad/s) of a Cartesian state (digest §1.3)."""
    x = np.asarray(x_a, dtype=np.float64)
    px, py, pz, vx, vy, vz = (x[..., i] for i in range(6))
    rho2 = px * px + py * py
    rho = np.sqrt(rho2)
    R2 = rho2 + pz * pz
    alpha_dot = (vx * py - vy * px) / rho2
    eps_dot = (vz * rho2 - pz * (px * vx + py * vy)) / (R2 * rho)
    return alpha_dot, eps_dot


def bistatic_state(x_a: ArrayLike, tx: ArrayLike) -> FloatArray:
    """Exact bistatic state x_b = [r_b, v_b, alpha, alpha_dot, eps, eps_dot] of a Cartesian state."""
    z = h_b(x_a, tx)
    ad, ed = angle_rates(x_a)
    return np.stack([z[..., 0], z[..., 3], z[..., 1], ad, z[..., 2], ed], axis=-1)


def bistatic_angle(p: ArrayLike, tx: ArrayLike) -> FloatArray:
    """Bistatic angle beta (rad) between the receiver and transmitter lines of sight at the target."""
    pos = np.asarray(p, dtype=np.float64)
    t = np.asarray(tx, dtype=np.float64)
    a = -pos
    b = t - pos
    cosb = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.arccos(np.clip(cosb, -1.0, 1.0))
