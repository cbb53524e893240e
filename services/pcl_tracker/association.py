"""Gating in bistatic coordinates and plot-to-track assignment (digest 003 §2.6 steps 3–4, §5.5 steps 2–3)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from .filter import innovation, mahalanobis2
from .geometry import BoolArray, FloatArray
from .ut import symmetrize

IntArray = NDArray[np.int64]


def gate_matrix(
    z_pred: FloatArray, R_pred: FloatArray, z: FloatArray, R_plot: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """d^2 (T, P) and ln det S (T, P) of every (track, plot) pair in the 4-D space (r_b, a, e, v_b).

    nu = z - z_pred (azimuth wrapped), S = R_pred + R_plot.
    """
    T, P = z_pred.shape[0], z.shape[0]
    if T == 0 or P == 0:
        return np.zeros((T, P)), np.zeros((T, P))
    nu = innovation(z[None, :, :], z_pred[:, None, :])
    S = symmetrize(R_pred[:, None, :, :] + R_plot[None, :, :, :])
    d2 = mahalanobis2(nu, S)
    _, logdet = np.linalg.slogdet(S)
    return d2, logdet


def assign_gnn(cost: FloatArray, gated: BoolArray) -> list[tuple[int, int]]:
    """Global nearest neighbour over gated pairs only (scipy's linear_sum_assignment).

    Non-gated pairs get a prohibitive cost and are discarded from the solution; rows and columns with no
    gated pair are left out before solving. Ties resolve by row/column order (tracks by id, plots by plot_id).
    """
    rows = np.flatnonzero(gated.any(axis=1))
    cols = np.flatnonzero(gated.any(axis=0))
    if rows.size == 0 or cols.size == 0:
        return []
    sub_g = gated[np.ix_(rows, cols)]
    sub_c = cost[np.ix_(rows, cols)]
    big = 1e6 + 10.0 * float(np.max(np.abs(sub_c[sub_g]))) if sub_g.any() else 1e6
    C = np.where(sub_g, sub_c, big)
    r, c = linear_sum_assignment(C)
    return [(int(rows[i]), int(cols[j])) for i, j in zip(r, c, strict=True) if sub_g[i, j]]


def assign_nn(cost: FloatArray, gated: BoolArray) -> list[tuple[int, int]]:
    """Greedy nearest neighbour: repeatedly take the gated pair of least cost among unused tracks and plots."""
    ti, pj = np.nonzero(gated)
    order = np.lexsort((pj, ti, cost[ti, pj]))
    used_t: set[int] = set()
    used_p: set[int] = set()
    out: list[tuple[int, int]] = []
    for k in order:
        t, p = int(ti[k]), int(pj[k])
        if t in used_t or p in used_p:
            continue
        used_t.add(t)
        used_p.add(p)
        out.append((t, p))
    return out
