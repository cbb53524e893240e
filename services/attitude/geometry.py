"""Frames and conversions of digest 004 (§1.2, eq. 1).

Frame E is radar-centred and flat: x north, y up, z east (right-handed). Azimuth beta is measured from +x
toward +z (clockwise from north seen from above), elevation eps from the horizontal plane, positive up.
All angles are radians unless a name says ``_deg``; all arrays are float64.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from shared.filters.angles import TWO_PI

F64 = NDArray[np.float64]


def spherical_to_cartesian(r_m: float, beta_rad: float, eps_rad: float) -> F64:
    """Eq. (1): h_xyz(r, beta, eps) = [r cos(beta) cos(eps), r sin(eps), r sin(beta) cos(eps)] in m."""
    ce = math.cos(eps_rad)
    return np.array([r_m * math.cos(beta_rad) * ce, r_m * math.sin(eps_rad), r_m * math.sin(beta_rad) * ce])


def cartesian_to_spherical(p: F64) -> tuple[float, float, float]:
    """Inverse of eq. (1): (r m, beta rad in [0, 2 pi), eps rad) of a position in E."""
    x, y, z = float(p[0]), float(p[1]), float(p[2])
    r = math.sqrt(x * x + y * y + z * z)
    beta = math.atan2(z, x) % TWO_PI
    eps = math.atan2(y, math.hypot(x, z))
    return r, beta, eps


def conversion_jacobian(r_m: float, beta_rad: float, eps_rad: float) -> F64:
    """H_theta = d h_xyz / d(r, beta, eps) (§2.2), evaluated at the given (measured) point."""
    cb, sb = math.cos(beta_rad), math.sin(beta_rad)
    ce, se = math.cos(eps_rad), math.sin(eps_rad)
    return np.array(
        [
            [cb * ce, -r_m * sb * ce, -r_m * cb * se],
            [se, 0.0, r_m * ce],
            [sb * ce, r_m * cb * ce, -r_m * sb * se],
        ]
    )


def convert_plot(
    r_m: float, beta_rad: float, eps_rad: float, sigma_r_m: float, sigma_beta_rad: float, sigma_eps_rad: float
) -> tuple[F64, F64]:
    """Eq. (1): converted position theta_xyz (m) and its covariance R_xyz = H R_rbe H^T (m^2), symmetric.

    H_theta is evaluated at the measured (r, beta, eps) (§2.2).
    """
    cb, sb = math.cos(beta_rad), math.sin(beta_rad)
    ce, se = math.cos(eps_rad), math.sin(eps_rad)
    z = np.array([r_m * cb * ce, r_m * se, r_m * sb * ce])
    # columns of H_theta scaled by the sigmas: d/dr, d/dbeta, d/deps; R_xyz = sum of their outer products
    ax, ay, az = cb * ce * sigma_r_m, se * sigma_r_m, sb * ce * sigma_r_m
    rb = r_m * sigma_beta_rad
    bx, bz = -sb * ce * rb, cb * ce * rb
    re = r_m * sigma_eps_rad
    cx, cy, cz = -cb * se * re, ce * re, -sb * se * re
    rxy = ax * ay + cx * cy
    rxz = ax * az + bx * bz + cx * cz
    ryz = ay * az + cy * cz
    rz = [
        [ax * ax + bx * bx + cx * cx, rxy, rxz],
        [rxy, ay * ay + cy * cy, ryz],
        [rxz, ryz, az * az + bz * bz + cz * cz],
    ]
    return z, np.array(rz)


def los_matrix(beta_rad: F64 | float, eps_rad: F64 | float, los_x: str = "radar_to_target") -> F64:
    """A_LE(beta, eps) of §1.2 (rows are the LOS axes written in E), shape (..., 3, 3).

    ``los_x="target_to_radar"`` left-multiplies by diag(-1, 1, -1).
    """
    b = np.asarray(beta_rad, dtype=np.float64)
    e = np.asarray(eps_rad, dtype=np.float64)
    cb, sb, ce, se = np.cos(b), np.sin(b), np.cos(e), np.sin(e)
    zero = np.zeros_like(cb)
    a = np.stack(
        [
            np.stack([ce * cb, se, ce * sb], axis=-1),
            np.stack([-se * cb, ce, -se * sb], axis=-1),
            np.stack([-sb, zero, cb], axis=-1),
        ],
        axis=-2,
    )
    if los_x == "target_to_radar":
        a = a * np.array([-1.0, 1.0, -1.0])[:, None]
    elif los_x != "radar_to_target":
        raise ValueError(f"unknown los_x {los_x!r}")
    return a


def body_axes(psi_rad: F64 | float, theta_rad: F64 | float, gamma_rad: F64 | float) -> tuple[F64, F64, F64]:
    """Body unit vectors i (nose), j (normal, up), k (starboard) written in E (§1.2), each shape (..., 3).

    Euler sequence from E: heading psi about y, pitch theta about the new z, roll gamma about x_b.
    """
    psi = np.asarray(psi_rad, dtype=np.float64)
    th = np.asarray(theta_rad, dtype=np.float64)
    ga = np.asarray(gamma_rad, dtype=np.float64)
    cp, sp, ct, st, cg, sg = np.cos(psi), np.sin(psi), np.cos(th), np.sin(th), np.cos(ga), np.sin(ga)
    i = np.stack([ct * cp, st, ct * sp], axis=-1)
    j = np.stack([-cg * st * cp - sg * sp, cg * ct, -cg * st * sp + sg * cp], axis=-1)
    k = np.stack([sg * st * cp - cg * sp, -sg * ct, sg * st * sp + cg * cp], axis=-1)
    return i, j, k
