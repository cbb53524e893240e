"""Track initiation by 2/L with the ring + ellipse gate, and the two-plot initial estimates (digest §2.3–§2.5)."""

from __future__ import annotations

from functools import partial

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from shared.filters.angles import wrap_pi
from shared.filters.covariance import CholeskyStats, symmetrize
from shared.filters.unscented import TransformResult, transform

from .geometry import BoolArray, FloatArray, h_a6


def ring_ellipse_test(
    zc1: FloatArray,
    Rc1: FloatArray,
    zc2: FloatArray,
    Rc2: FloatArray,
    tau2: FloatArray,
    v_min: float,
    v_max: float,
    gamma3: float,
) -> tuple[BoolArray, FloatArray, FloatArray]:
    """Ring gate augmented with the chi2 test, for pairs broadcast over leading axes.

    zc1/zc2 (..., 3) converted positions (m), Rc1/Rc2 (..., 3, 3), tau2 (...) = t(2) - t(1) (s).
    Returns (passed, s, rho): s = -1 inside the inner circle, 0 in the ring, +1 outside the outer circle;
    rho = (z_c(2) - z_m)^T (R_c(1) + R_c(2))^-1 (z_c(2) - z_m) with z_m = z_c(1) + R e_12 (0 where s = 0).
    """
    d = zc2 - zc1
    d12 = np.linalg.norm(d, axis=-1)
    R_min = v_min * tau2
    R_max = v_max * tau2
    s = np.where(d12 < R_min, -1.0, np.where(d12 > R_max, 1.0, 0.0))
    R = np.where(s > 0, R_max, R_min)
    safe = d12 > 0.0
    e12 = np.where(safe[..., None], d / np.where(safe, d12, 1.0)[..., None], np.array([1.0, 0.0, 0.0]))
    z_m = zc1 + R[..., None] * e12
    r = zc2 - z_m
    S = Rc1 + Rc2
    rho = np.einsum("...i,...i->...", r, np.linalg.solve(S, r[..., None])[..., 0])
    rho = np.where(s == 0.0, 0.0, rho)
    passed = (s == 0.0) | (rho < gamma3)
    return passed, s, rho


#: relative slack of the exact pruning bound (it only discards pairs that are clearly outside)
_BOUND_SLACK = 1.0 + 1e-9


def ring_gate_pairs(
    zc1: FloatArray,
    Rc1: FloatArray,
    tau1: FloatArray,
    zc2: FloatArray,
    Rc2: FloatArray,
    v_min: float,
    v_max: float,
    gamma3: float,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Every (first plot i, second plot j) pair that passes :func:`ring_ellipse_test`, sorted by (i, j).

    zc1 (C, 3), Rc1 (C, 3, 3), tau1 (C,) = t(2) - t(1) per first plot; zc2 (P, 3), Rc2 (P, 3, 3).
    Exact pruning: outside the ring, z_c(2) - z_m = (d12 - R) e12 and rho >= (d12 - R)² / tr(R_c(1) + R_c(2))
    (the largest eigenvalue is at most the trace), so a pair can pass only if
    d12 <= R_max + sqrt(gamma3 tr(R_c(1))) + sqrt(gamma3 tr(R_c(2))). A k-d tree of the second plots gives
    the pairs within that reach; the bound and then the full test decide the rest.
    """
    C, P = zc1.shape[0], zc2.shape[0]
    empty = np.zeros(0, dtype=np.int64)
    if C == 0 or P == 0:
        return empty, empty
    tr1 = np.trace(Rc1, axis1=-2, axis2=-1)
    tr2 = np.trace(Rc2, axis1=-2, axis2=-1)
    reach = v_max * tau1 + np.sqrt(gamma3 * _BOUND_SLACK * tr1) + float(np.sqrt(gamma3 * _BOUND_SLACK * tr2.max()))
    found = cKDTree(zc2).query_ball_point(zc1, reach * (1.0 + 1e-9) + 1e-6)
    counts = np.fromiter((len(f) for f in found), dtype=np.int64, count=C)
    if counts.sum() == 0:
        return empty, empty
    ci = np.repeat(np.arange(C, dtype=np.int64), counts)
    pj = np.fromiter((j for f in found for j in f), dtype=np.int64, count=int(counts.sum()))
    tau = tau1[ci]
    d12 = np.linalg.norm(zc2[pj] - zc1[ci], axis=-1)
    R_min, R_max = v_min * tau, v_max * tau
    miss = np.where(d12 > R_max, d12 - R_max, np.where(d12 < R_min, R_min - d12, 0.0))
    keep = miss * miss <= gamma3 * _BOUND_SLACK * (tr1[ci] + tr2[pj])
    ci, pj = ci[keep], pj[keep]
    if ci.size == 0:
        return empty, empty
    passed, _, _ = ring_ellipse_test(zc1[ci], Rc1[ci], zc2[pj], Rc2[pj], tau1[ci], v_min, v_max, gamma3)
    ci, pj = ci[passed], pj[passed]
    order = np.lexsort((pj, ci))
    return ci[order], pj[order]


def two_plot_bistatic_estimate(
    z1: FloatArray, sig1: FloatArray, z2: FloatArray, sig2: FloatArray, tau2: FloatArray, init_cov: str = "full"
) -> tuple[FloatArray, FloatArray]:
    """x_b(2) = [r_b, v_b, a, a_dot, e, e_dot] and P_b(2) from two plots (digest §2.4).

    z = [r_b, a, e, v_b] (m, rad, rad, m/s), sig in the same units; r_b, v_b, a, e from the second plot;
    angle rates by differencing (azimuth difference wrapped). ``init_cov="full"`` adds the correct
    cross terms cov(a, a_dot) = sigma_a(2)^2 / tau, cov(e, e_dot) = sigma_e(2)^2 / tau [D];
    ``"paper_diagonal"`` is the paper's diagonal P_b(2).
    """
    tau = np.asarray(tau2, dtype=np.float64)
    a_dot = wrap_pi(z2[:, 1] - z1[:, 1]) / tau
    e_dot = (z2[:, 2] - z1[:, 2]) / tau
    xb = np.stack([z2[:, 0], z2[:, 3], z2[:, 1], a_dot, z2[:, 2], e_dot], axis=-1)
    var_a_dot = (sig1[:, 1] ** 2 + sig2[:, 1] ** 2) / tau**2
    var_e_dot = (sig1[:, 2] ** 2 + sig2[:, 2] ** 2) / tau**2
    diag = np.stack([sig2[:, 0] ** 2, sig2[:, 3] ** 2, sig2[:, 1] ** 2, var_a_dot, sig2[:, 2] ** 2, var_e_dot], -1)
    Pb = np.zeros((xb.shape[0], 6, 6))
    idx = np.arange(6)
    Pb[:, idx, idx] = diag
    if init_cov == "full":
        Pb[:, 2, 3] = Pb[:, 3, 2] = sig2[:, 1] ** 2 / tau
        Pb[:, 4, 5] = Pb[:, 5, 4] = sig2[:, 2] ** 2 / tau
    elif init_cov != "paper_diagonal":
        raise ValueError(f"unknown init_cov {init_cov!r}")
    return xb, Pb


def _h_a6_map(tx: FloatArray, pts: FloatArray) -> FloatArray:
    return h_a6(pts, tx)[0]


def bistatic_to_cartesian(
    xb: FloatArray, Pb: FloatArray, tx: FloatArray, kind: str = "unscented", stats: CholeskyStats | None = None
) -> TransformResult:
    """UT (n = 6) of a bistatic state through h_a^(6) -> x_a, P_a (initialisation and BKF handover)."""
    return transform(kind, xb, Pb, partial(_h_a6_map, tx), None, stats, with_cross=False)


def ukf_only_init(
    zc1: FloatArray, Rc1: FloatArray, zc2: FloatArray, Rc2: FloatArray, tau2: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Cartesian two-plot initialisation of the "UKF only" comparison scheme (digest §2.5 [D]).

    x = [z_c(2); (z_c(2) - z_c(1)) / tau], P = [[R2, R2/tau], [R2/tau, (R1 + R2)/tau^2]].
    """
    tau = np.asarray(tau2, dtype=np.float64)[:, None, None]
    x = np.concatenate([zc2, (zc2 - zc1) / tau[:, :, 0]], axis=-1)
    P = np.zeros((zc1.shape[0], 6, 6))
    P[:, :3, :3] = Rc2
    P[:, :3, 3:] = Rc2 / tau
    P[:, 3:, :3] = Rc2 / tau
    P[:, 3:, 3:] = (Rc1 + Rc2) / tau**2
    return x, symmetrize(P)
