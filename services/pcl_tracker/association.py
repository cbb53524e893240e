"""Gating in bistatic coordinates and plot-to-track assignment (digest 003 §2.6 steps 3–4, §5.5 steps 2–3).

:func:`gate_matrix` computes d² for every (track, plot) pair; :func:`gate_pairs` finds the same gated pairs
without forming all T × P innovation covariances (what the core uses), and :func:`assign_pairs` runs GNN or
NN on such a sparse set of pairs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from shared.filters import kalman
from shared.filters.covariance import symmetrize

from .filter import innovation
from .geometry import BoolArray, FloatArray

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
    d2 = kalman.nis(nu, S)
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


#: relative slack of the exact pre-gating bounds (they only discard pairs that are clearly outside)
_BOUND_SLACK = 1.0 + 1e-9
_Z_IDX = np.arange(4)


@dataclass
class GatedPairs:
    """The (track, plot) pairs inside the 4-D gate, sorted by track then plot, with d² and ln det S."""

    track: IntArray  # (K,) row index of the track
    plot: IntArray  # (K,) column index of the plot
    d2: FloatArray  # (K,)
    logdet: FloatArray  # (K,)

    @classmethod
    def empty(cls) -> GatedPairs:
        return cls(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0))

    def __len__(self) -> int:
        return int(self.track.size)


def gate_pairs(z_pred: FloatArray, R_pred: FloatArray, z: FloatArray, R_plot: FloatArray, gamma: float) -> GatedPairs:
    """The pairs with d² = nu^T S^-1 nu <= gamma, exactly as :func:`gate_matrix` decides them.

    Pruning is exact: for a positive-definite S, the Mahalanobis distance of one component is a lower
    bound of the full one (nu_c² / S_cc <= d²). Candidates come from a window on the sorted r_b of the
    plots (the track's predicted r_b ± sqrt(gamma (R_pred,rr + the largest plot variance))), the four
    one-component bounds discard more, and d² is computed as in :func:`gate_matrix` for what is left.
    Cost: O(T log P) plus the candidates, instead of T × P 4×4 solves.
    """
    T, P = z_pred.shape[0], z.shape[0]
    if T == 0 or P == 0:
        return GatedPairs.empty()
    order = np.argsort(z[:, 0], kind="stable")
    rb_sorted = z[order, 0]
    var_plot = R_plot[:, _Z_IDX, _Z_IDX]  # (P, 4)
    var_pred = R_pred[:, _Z_IDX, _Z_IDX]  # (T, 4)
    half = np.sqrt(gamma * _BOUND_SLACK * (var_pred[:, 0] + float(var_plot[:, 0].max()))) + 1e-6
    lo = np.searchsorted(rb_sorted, z_pred[:, 0] - half, side="left")
    hi = np.searchsorted(rb_sorted, z_pred[:, 0] + half, side="right")
    counts = np.maximum(hi - lo, 0)
    n = int(counts.sum())
    if n == 0:
        return GatedPairs.empty()
    ti = np.repeat(np.arange(T, dtype=np.int64), counts)
    starts = np.repeat(lo - (np.cumsum(counts) - counts), counts)
    pj = order[starts + np.arange(n)]
    nu = innovation(z[pj], z_pred[ti])
    keep = np.all(nu * nu <= gamma * _BOUND_SLACK * (var_pred[ti] + var_plot[pj]), axis=1)
    ti, pj, nu = ti[keep], pj[keep], nu[keep]
    if ti.size == 0:
        return GatedPairs.empty()
    S = symmetrize(R_pred[ti] + R_plot[pj])
    d2 = kalman.nis(nu, S)
    inside = d2 <= gamma
    ti, pj, d2, S = ti[inside], pj[inside], d2[inside], S[inside]
    _, logdet = np.linalg.slogdet(S) if ti.size else (None, np.zeros(0))
    srt = np.lexsort((pj, ti))
    return GatedPairs(ti[srt], pj[srt], d2[srt], np.asarray(logdet, dtype=np.float64)[srt])


def gate_pairs_models(
    z_pred: FloatArray, R_pred: FloatArray, z: FloatArray, R_plot: FloatArray, gamma: float
) -> GatedPairs:
    """[E] IMM gating: the union of the models' gates. z_pred (T, r, 4), R_pred (T, r, 4, 4) per model.

    A plot is in a track's gate when it is inside the gate of at least one of its models (a manoeuvre that the
    low-noise model's gate misses is still caught by the high-noise model's); each pair keeps its least d²
    over those models, and that model's ln det S.
    """
    T, r = z_pred.shape[:2]
    gp = gate_pairs(z_pred.reshape(T * r, 4), R_pred.reshape(T * r, 4, 4), z, R_plot, gamma)
    if len(gp) == 0:
        return gp
    track = gp.track // r
    order = np.lexsort((gp.d2, gp.plot, track))
    track, plot, d2, logdet = track[order], gp.plot[order], gp.d2[order], gp.logdet[order]
    first = np.ones(track.size, dtype=bool)
    first[1:] = (track[1:] != track[:-1]) | (plot[1:] != plot[:-1])
    return GatedPairs(track[first], plot[first], d2[first], logdet[first])


def assign_pairs(
    pairs: GatedPairs, cost: FloatArray, rows_allowed: BoolArray, cols_free: BoolArray, method: str = "gnn"
) -> list[tuple[int, int]]:
    """GNN (or NN) over the gated pairs whose track is allowed and whose plot is still free, sorted by track.

    The same solution as :func:`assign_gnn` / :func:`assign_nn` on the dense matrices. GNN with a
    prohibitive cost for non-gated pairs maximises the number of gated pairs and then minimises their total
    cost, which separates over the connected components of the bipartite graph of gated pairs: each
    component is solved on its own (a lone track–plot pair directly), rows and columns in ascending order.
    """
    sel = rows_allowed[pairs.track] & cols_free[pairs.plot]
    if not sel.any():
        return []
    ti, pj, c = pairs.track[sel], pairs.plot[sel], cost[sel]
    rows, r_inv = np.unique(ti, return_inverse=True)
    cols, c_inv = np.unique(pj, return_inverse=True)
    if method != "gnn":
        C = np.zeros((rows.size, cols.size))
        G = np.zeros((rows.size, cols.size), dtype=bool)
        C[r_inv, c_inv] = c
        G[r_inv, c_inv] = True
        return [(int(rows[r]), int(cols[k])) for r, k in assign_nn(C, G)]
    n_r, n_c = rows.size, cols.size
    graph = coo_matrix((np.ones(ti.size), (r_inv, n_r + c_inv)), shape=(n_r + n_c, n_r + n_c))
    _, labels = connected_components(graph, directed=False)
    row_lab, col_lab = labels[:n_r], labels[n_r:]
    n_rows_of = np.bincount(row_lab, minlength=labels.max() + 1)
    n_cols_of = np.bincount(col_lab, minlength=labels.max() + 1)
    out: list[tuple[int, int]] = []
    single = (n_rows_of[row_lab[r_inv]] == 1) & (n_cols_of[row_lab[r_inv]] == 1)  # lone pair components
    for r, k in zip(r_inv[single].tolist(), c_inv[single].tolist(), strict=True):
        out.append((int(rows[r]), int(cols[k])))
    rest = ~single
    if rest.any():
        pr, pc, pv = r_inv[rest], c_inv[rest], c[rest]
        lab = row_lab[pr]
        order = np.argsort(lab, kind="stable")
        pr, pc, pv, lab = pr[order], pc[order], pv[order], lab[order]
        bounds = np.flatnonzero(np.diff(lab)) + 1
        for sr, sc, sv in zip(np.split(pr, bounds), np.split(pc, bounds), np.split(pv, bounds), strict=True):
            ur, ir = np.unique(sr, return_inverse=True)
            uc, ic = np.unique(sc, return_inverse=True)
            C = np.zeros((ur.size, uc.size))
            G = np.zeros((ur.size, uc.size), dtype=bool)
            C[ir, ic] = sv
            G[ir, ic] = True
            out += [(int(rows[ur[a]]), int(cols[uc[b]])) for a, b in assign_gnn(C, G)]
    out.sort()
    return out
