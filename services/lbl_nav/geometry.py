"""Launch geometry: the baseline rotation (3), the difference-of-squares pseudo-measurement (4)/(U1),
the grid of starting points (U2) and mirror reflection across a beacon line.

Frame: x = East, y = North (m). alpha is the azimuth of the beacon line, clockwise from y (rad).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


def baseline_azimuth(x1: float, y1: float, x2: float, y2: float) -> float:
    """alpha = atan2(x2 - x1, y2 - y1): azimuth from beacon 1 to beacon 2, rad (Eq. 3)."""
    return math.atan2(x2 - x1, y2 - y1)


def rotate(x: F64 | float, y: F64 | float, alpha: float) -> tuple[F64, F64]:
    """Eq. (3): xbar = x cos a - y sin a, ybar = x sin a + y cos a (ybar runs along the beacon line)."""
    c, s = math.cos(alpha), math.sin(alpha)
    xa, ya = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    return xa * c - ya * s, xa * s + ya * c


def unrotate(xb: F64 | float, yb: F64 | float, alpha: float) -> tuple[F64, F64]:
    """Inverse of (3): x = xbar cos a + ybar sin a, y = -xbar sin a + ybar cos a."""
    c, s = math.cos(alpha), math.sin(alpha)
    xa, ya = np.asarray(xb, dtype=np.float64), np.asarray(yb, dtype=np.float64)
    return xa * c + ya * s, -xa * s + ya * c


def pseudo_rho(y1_m: float, y2_m: float, yb1_m: float, yb2_m: float, dz1_m: float, dz2_m: float) -> float:
    """Eq. (4): rho = 1/2 [y1^2 - y2^2 - ybar1^2 + ybar2^2 - dz1^2 + dz2^2], dz_k = z^k - z_0 (m^2 / m)."""
    return 0.5 * (y1_m**2 - y2_m**2 - yb1_m**2 + yb2_m**2 - dz1_m**2 + dz2_m**2)


def ybar0_two(y1_m: float, y2_m: float, yb1_m: float, yb2_m: float, dz1_m: float, dz2_m: float) -> float:
    """(U1): ybar_0 = rho / (ybar2 - ybar1), the along-baseline coordinate of the vehicle, m."""
    return pseudo_rho(y1_m, y2_m, yb1_m, yb2_m, dz1_m, dz2_m) / (yb2_m - yb1_m)


def ybar0_multi(ranges_m: F64, ybars_m: F64, dz_m: F64) -> float:
    """[R] n_0 >= 3 on one line: least squares over the pairs (1, j) of rho_1j = (ybar_j - ybar_1) ybar_0."""
    d = ybars_m[1:] - ybars_m[0]
    rho = np.array(
        [
            pseudo_rho(ranges_m[0], ranges_m[j], ybars_m[0], ybars_m[j], dz_m[0], dz_m[j])
            for j in range(1, ranges_m.size)
        ]
    )
    return float(np.dot(d, rho) / np.dot(d, d))


def grid_xbar(xb_m: float, half_width_m: float, L: int) -> F64:
    """(U2) with [R] bounds: L nodes from xb - half_width to xb + half_width, step Delta x / (L - 1)."""
    return xb_m - half_width_m + np.arange(L, dtype=np.float64) * (2.0 * half_width_m / (L - 1))


def reflect_point(x: float, y: float, alpha: float, xb_m: float) -> tuple[float, float]:
    """Mirror image of (x, y) across the line xbar = xb (the beacon line of azimuth alpha)."""
    xr, yr = rotate(x, y, alpha)
    xm, ym = unrotate(2.0 * xb_m - xr, yr, alpha)
    return float(xm), float(ym)


def principal_axis(xs_m: F64, ys_m: F64) -> tuple[float, float]:
    """Azimuth of the best-fit line of the points and the smallest principal spread (rms distance to it), m."""
    pts = np.column_stack([xs_m, ys_m])
    centred = pts - pts.mean(axis=0)
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    d = vt[0]
    if d[1] < 0 or (d[1] == 0 and d[0] < 0):
        d = -d
    spread = float(sv[-1] / math.sqrt(pts.shape[0])) if sv.size > 1 else 0.0
    return math.atan2(float(d[0]), float(d[1])), spread
