"""Motion and measurement models of the vertical channel (digest §1.4, §1.5, §1.7, §2.2).

State per hypothesis s = [da, dV, dh] (m/s^2, m/s, m), correction convention (true = indicated + d).

* transition (eq. 3): ``Phi(T) = [[1, 0, 0], [T, 1, 0], [phi31, T, 1]]``, phi31 = T^2/2 ("exact") or 0 ("euler");
* process noise: continuous white noise of density q_a on da, plus optional q_h*T on dh;
* measurement of hypothesis ij: ``y_ij = H_ij + h_ra - h_ins = dh + n``, C = [0, 0, 1];
* measurement variance of a cell-rate measurement built from n_k raw samples:
  ``R_k = sigma_v^2/n_k + sigma_map^2 + c_q*D1``;
* the slope term of a fix's dh (``vertical_slope_term``): the map value of a cell belongs to its centre, so the
  dh of hypothesis ij is the altitude error *at the cell centres*; where the aircraft is off the centres by e
  (the fix's horizontal error) the terrain under it differs by g.e, g the slope, and dh is off by the mean of
  g.e over the window. Over smooth terrain the slope keeps its sign along the track and this bias does not
  average out. Its variance is ``g_bar^T Cov_xz g_bar``; a refined (sub-cell) fix moves the position by d from
  the centres, and dh by g_bar.d (docs/terrain_nav.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from .geometry import F64

if TYPE_CHECKING:
    from .maps import ReferenceMap
    from .resampler import CellMeasurement


def phi31(T: float, mode: str = "exact") -> float:
    """Row-3 coupling of da into dh over T seconds: T^2/2 (exact) or 0 (Euler)."""
    return 0.5 * T * T if mode == "exact" else 0.0


def transition(T: float, mode: str = "exact") -> F64:
    """Phi(T) of eq. (3)."""
    return np.array([[1.0, 0.0, 0.0], [T, 1.0, 0.0], [phi31(T, mode), T, 1.0]])


def process_noise(T: float, q_a: float, q_h: float = 0.0) -> F64:
    """Q(T) for white noise of density q_a driving da (a random walk), plus diag(0, 0, q_h*T)."""
    T2, T3, T4, T5 = T * T, T**3, T**4, T**5
    Q = q_a * np.array(
        [
            [T, T2 / 2.0, T3 / 6.0],
            [T2 / 2.0, T3 / 3.0, T4 / 8.0],
            [T3 / 6.0, T4 / 8.0, T5 / 20.0],
        ]
    )
    Q[2, 2] += q_h * T
    return Q


def measurement_variance(n_k: int, sigma_v_m: float, sigma_map_m: float, c_q: float, D1_m2: float) -> float:
    """R_k = sigma_v^2/n_k + sigma_map^2 + c_q*D1 (m^2) of a measurement averaged over n_k raw samples."""
    return sigma_v_m * sigma_v_m / max(n_k, 1) + sigma_map_m * sigma_map_m + c_q * D1_m2


def mean_slope(window: Sequence[CellMeasurement], ref: ReferenceMap, i: int, j: int) -> F64:
    """g_bar: the mean map slope (dH/dx, dH/dz; m/m) over the cells hypothesis (i, j) reads in ``window``;
    zeros without a measurement or where the slopes are all void."""
    g = np.zeros(2)
    if not window:
        return g
    gx, gz = ref.slope()
    rows = np.fromiter((m.I + i for m in window), dtype=np.int64, count=len(window))
    cols = np.fromiter((m.J + j for m in window), dtype=np.int64, count=len(window))
    sx, sz = gx[rows, cols], gz[rows, cols]
    ok = np.isfinite(sx) & np.isfinite(sz)
    if ok.any():
        g[0], g[1] = float(sx[ok].mean()), float(sz[ok].mean())
    return g
