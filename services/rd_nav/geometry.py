"""RD-LBL measurement model, noise covariance, CRLB/GDOP and snapshot Gauss-Newton (digest §4.2, §4.5, §4.6).

Frame: base-station NED, metres (x north, y east, z down). Positions of beacons are 3-vectors; the moving
receiver's horizontal position ``p = (x, y)`` is estimated and its depth ``z`` is measured.

Observables of one cycle with leader A1 and followers Aj, j = 1..M (Eq. 1-2 with reply delays, §4.2):

* ``s_j = c_est (dT_1j - tau_j) = r_1j + rho_j - rho_1``   total path difference
* ``d_j = s_j - r_1j = rho_j(t_j) - rho_1(t_1)``            range difference (hyperbola, foci A1, Aj)
* ``h_j(p) = ||(p + delta_j, z_j) - X_Aj|| - ||(p, z_1) - X_A1||`` with ``delta_j`` the receiver's DR
  displacement between its leader and follower arrivals (motion compensation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from shared.filters.covariance import symmetrize

F64 = NDArray[np.floating[Any]]  # float64 throughout; typed loosely for numpy's linalg results


def as_f64(a: object) -> F64:
    return np.asarray(a, dtype=np.float64)


def leader_follower_ranges(leader: F64, followers: F64) -> F64:
    """r_1j = ||X_Aj - X_A1||, m, shape (M,)."""
    return np.sqrt(np.sum((followers - leader[None, :]) ** 2, axis=1))


def predict_d(P: F64, leader: F64, followers: F64, delta: F64, z1: float, zj: F64) -> F64:
    """h_j(p) for every row of P (N, 2) -> (N, M), metres (vectorised over particles).

    ``delta`` is (M, 2), or (N, M, 2) for a motion compensation of each particle's own."""
    dz1 = z1 - leader[2]
    rho1 = np.sqrt((P[:, 0] - leader[0]) ** 2 + (P[:, 1] - leader[1]) ** 2 + dz1 * dz1)
    qx = P[:, 0:1] + (delta[..., 0] - followers[:, 0])
    qy = P[:, 1:2] + (delta[..., 1] - followers[:, 1])
    dzj = (zj - followers[:, 2])[None, :]
    rhoj = np.sqrt(qx * qx + qy * qy + dzj * dzj)
    return rhoj - rho1[:, None]


def jacobian_d(P: F64, leader: F64, followers: F64, delta: F64, z1: float, zj: F64) -> F64:
    """dh/dp at every row of P (K, 2) -> (K, M, 2): rows (u_j - u_1)_xy, u = unit vector beacon -> receiver."""
    v1 = np.empty((P.shape[0], 3))
    v1[:, 0] = P[:, 0] - leader[0]
    v1[:, 1] = P[:, 1] - leader[1]
    v1[:, 2] = z1 - leader[2]
    u1 = v1 / np.linalg.norm(v1, axis=1)[:, None]
    vj = np.empty((P.shape[0], followers.shape[0], 3))
    vj[:, :, 0] = P[:, 0:1] + (delta[:, 0] - followers[:, 0])[None, :]
    vj[:, :, 1] = P[:, 1:2] + (delta[:, 1] - followers[:, 1])[None, :]
    vj[:, :, 2] = (zj - followers[:, 2])[None, :]
    uj = vj / np.linalg.norm(vj, axis=2)[:, :, None]
    return uj[:, :, :2] - u1[:, None, :2]


def error_jacobian(U: F64, G: F64) -> F64:
    """dh/de (M, 3) of the DR error states e. Follower j's motion compensation is delta_j - G_j e and h_j depends
    on delta_j only through rho_j (the leader's range does not move with it), so dh_j/de = -u_j^T G_j, with u_j
    (M, 2) the horizontal unit vectors follower j -> receiver (:func:`follower_units`) and G (M, 2, 3) the
    position error per unit of each state (:mod:`.drift`). The joint Jacobian over [p, e] is ``[H, dh/de]``."""
    return -np.einsum("mi,mij->mj", U, G)


def noise_free_tdoa(
    receiver: F64, leader: F64, followers: F64, tau_s: F64, c_mps: float
) -> tuple[F64, F64, F64, F64, float]:
    """Static receiver, no noise: (dT_1j [s], d_j [m], s_j [m], rho_j [m], rho_1 [m]) per Eq. (1)-(2) + tau."""
    rho1 = float(np.linalg.norm(receiver - leader))
    rhoj = np.linalg.norm(followers - receiver[None, :], axis=1)
    r1j = leader_follower_ranges(leader, followers)
    s = r1j + rhoj - rho1
    dT = s / c_mps + tau_s
    return dT, s - r1j, s, rhoj, rho1


def in_window(s_m: F64, r1j_m: F64, tol_m: float) -> NDArray[np.bool_]:
    """Validity window -tol <= s_j <= 2 r_1j + tol (triangle inequality, §4.2)."""
    return (s_m >= -tol_m) & (s_m <= 2.0 * r1j_m + tol_m)


def measurement_cov(
    s_m: F64,
    c_mps: float,
    sigma_t_s: float,
    sigma_f_s: float = 0.0,
    sigma_c_mps: float = 0.0,
    node_term: F64 | None = None,
) -> F64:
    """R (M x M, m^2) = c^2 [sigma_t^2 (I + 1 1^T) + sigma_f^2 I] + (sigma_c/c)^2 s s^T [+ J_A Sigma_A J_A^T]."""
    M = s_m.shape[0]
    eye = np.eye(M)
    R = c_mps * c_mps * (sigma_t_s * sigma_t_s * (eye + np.ones((M, M))) + sigma_f_s * sigma_f_s * eye)
    if sigma_c_mps > 0.0:
        k = sigma_c_mps / c_mps
        R = R + k * k * np.outer(s_m, s_m)
    if node_term is not None:
        R = R + node_term
    return symmetrize(R)


def node_cov_term(
    p: F64, z1: float, zj: F64, delta: F64, leader: F64, followers: F64, sigma_leader_m: float, sigma_f_m: F64
) -> F64:
    """J_A Sigma_A J_A^T for isotropic per-axis beacon-coordinate errors (§4.2), m^2.

    ds_j/dX_A1 = e(A1->X) - e(A1->Aj);  ds_j/dX_Aj = e(A1->Aj) - e(Aj->X).
    """
    x1 = np.array([p[0], p[1], z1])
    e1x = (x1 - leader) / np.linalg.norm(x1 - leader)
    xj = np.column_stack([p[0] + delta[:, 0], p[1] + delta[:, 1], zj])
    ejx = (xj - followers) / np.linalg.norm(xj - followers, axis=1)[:, None]
    e1j = (followers - leader[None, :]) / np.linalg.norm(followers - leader[None, :], axis=1)[:, None]
    g = e1x[None, :] - e1j  # (M, 3) sensitivity to the leader
    hj = e1j - ejx  # (M, 3) sensitivity to the own follower
    term = sigma_leader_m**2 * (g @ g.T)
    term = term + np.diag(sigma_f_m**2 * np.sum(hj * hj, axis=1))
    return symmetrize(term)


def motion_comp_cov(p: F64, zj: F64, delta: F64, followers: F64, dt_s: F64, sigma_v_mps: float) -> F64:
    """Covariance of h_j from a DR velocity error (isotropic sigma_v per axis, constant over the cycle) that
    corrupts the motion compensation delta_j = v dt_j: sigma_v^2 dt_j dt_k (u_j . u_k)_xy, m^2 ([E])."""
    v = np.column_stack(
        [p[0] + delta[:, 0] - followers[:, 0], p[1] + delta[:, 1] - followers[:, 1], zj - followers[:, 2]]
    )
    u = v[:, :2] / np.linalg.norm(v, axis=1)[:, None]
    g = u * dt_s[:, None]
    return sigma_v_mps**2 * (g @ g.T)


def follower_units(p: F64, zj: F64, delta: F64, followers: F64) -> F64:
    """Horizontal part of the unit vectors follower j -> receiver at its arrival (p + delta_j), (M, 2)."""
    v = np.column_stack(
        [p[0] + delta[:, 0] - followers[:, 0], p[1] + delta[:, 1] - followers[:, 1], zj - followers[:, 2]]
    )
    return v[:, :2] / np.linalg.norm(v, axis=1)[:, None]


def fisher(H: F64, R: F64) -> F64:
    """H^T R^-1 H (2 x 2)."""
    return H.T @ np.linalg.solve(R, H)


def crlb(H: F64, R: F64) -> F64:
    """Single-cycle Cramer-Rao bound P_CRLB = (H^T R^-1 H)^-1 on the horizontal position, m^2."""
    F = fisher(H, R)
    P = np.linalg.inv(F)
    return symmetrize(P)


def drms(P: F64) -> float:
    return math.sqrt(max(float(np.trace(P)), 0.0))


def geometry_at(p: F64, beacons: F64, z: float, leader: int = 0, delta: F64 | None = None) -> tuple[F64, F64, F64]:
    """(H (M,2), s (M,), r1j (M,)) for a static receiver at p, depth z; beacons (M+1, 3), leader index."""
    L = beacons[leader]
    Fw = np.delete(beacons, leader, axis=0)
    M = Fw.shape[0]
    dl = np.zeros((M, 2)) if delta is None else delta
    zj = np.full(M, z)
    H = jacobian_d(p.reshape(1, 2), L, Fw, dl, z, zj)[0]
    pp = np.array([p[0], p[1], z])
    r1j = leader_follower_ranges(L, Fw)
    s = r1j + np.linalg.norm(Fw - pp[None, :], axis=1) - float(np.linalg.norm(pp - L))
    return H, s, r1j


def gdop(p: F64, beacons: F64, z: float, leader: int = 0) -> float:
    """GDOP = DRMS / (c sigma_t) with only receiver arrival-time noise (sigma_f = sigma_c = 0), §4.6."""
    H, _, _ = geometry_at(p, beacons, z, leader)
    M = H.shape[0]
    R = np.eye(M) + np.ones((M, M))
    try:
        return drms(crlb(H, R))
    except np.linalg.LinAlgError:
        return math.inf


def crlb_at(
    p: F64,
    beacons: F64,
    z: float,
    c_mps: float,
    sigma_t_s: float,
    sigma_c_mps: float = 0.0,
    sigma_f_s: float = 0.0,
    leader: int = 0,
) -> F64:
    """P_CRLB (2 x 2, m^2) for a static receiver at p with the full R of §4.2."""
    H, s, _ = geometry_at(p, beacons, z, leader)
    R = measurement_cov(s, c_mps, sigma_t_s, sigma_f_s, sigma_c_mps)
    return crlb(H, R)


def sound_speed_bias(p: F64, beacons: F64, z: float, eps: float, R: F64 | None = None, leader: int = 0) -> F64:
    """Linearised position bias b = (H^T R^-1 H)^-1 H^T R^-1 (eps s) of a relative sound-speed error eps (§4.6)."""
    H, s, _ = geometry_at(p, beacons, z, leader)
    W = np.linalg.inv(R) if R is not None else np.linalg.inv(np.eye(s.size) + np.ones((s.size, s.size)))
    return np.linalg.solve(H.T @ W @ H, H.T @ W @ (eps * s))


@dataclass(frozen=True)
class GnResult:
    """Batch Gauss-Newton result: one row per start."""

    p: F64  # (K, 2) solutions, m
    converged: NDArray[np.bool_]  # (K,)
    iterations: NDArray[np.int64]  # (K,) updates taken until the step fell below tol
    residual_m: F64  # (K,) ||d - h(p)||


def gauss_newton(
    d: F64,
    starts: F64,
    leader: F64,
    followers: F64,
    delta: F64,
    z1: float,
    zj: F64,
    W: F64 | None = None,
    max_iter: int = 30,
    step_limit_m: float = 200.0,
    tol_m: float = 1e-3,
) -> GnResult:
    """Snapshot (weighted) Gauss-Newton from K starts at once (§4.5).

    ``d`` is (M,) or (K, M). With M = 2 the problem is square and the step is H^-1 e; with M >= 3 it is
    the weighted LS step (H^T W H)^-1 H^T W e, W = R^-1. The step is limited to ``step_limit_m``.
    """
    X = np.array(starts, dtype=np.float64, copy=True).reshape(-1, 2)
    K = X.shape[0]
    D = np.broadcast_to(d, (K, followers.shape[0]))
    Wm = np.eye(followers.shape[0]) if W is None else W
    done = np.zeros(K, dtype=bool)
    bad = np.zeros(K, dtype=bool)
    iters = np.zeros(K, dtype=np.int64)
    for _ in range(max_iter):
        act = ~(done | bad)
        if not act.any():
            break
        Xa = X[act]
        e = D[act] - predict_d(Xa, leader, followers, delta, z1, zj)
        H = jacobian_d(Xa, leader, followers, delta, z1, zj)
        HtW = np.einsum("kmi,mn->kin", H, Wm)
        A = np.einsum("kin,knj->kij", HtW, H)
        b = np.einsum("kin,kn->ki", HtW, e)
        det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
        scale = np.abs(A).max(axis=(1, 2)) ** 2
        sing = ~(np.abs(det) > 1e-14 * scale)
        det_safe = np.where(sing, 1.0, det)
        step = np.empty_like(b)
        step[:, 0] = (A[:, 1, 1] * b[:, 0] - A[:, 0, 1] * b[:, 1]) / det_safe
        step[:, 1] = (A[:, 0, 0] * b[:, 1] - A[:, 1, 0] * b[:, 0]) / det_safe
        step[sing] = 0.0
        norm = np.hypot(step[:, 0], step[:, 1])
        too_big = norm > step_limit_m
        step[too_big] *= (step_limit_m / norm[too_big])[:, None]
        idx = np.flatnonzero(act)
        X[idx] += step
        iters[idx] += 1
        bad[idx[sing | ~np.isfinite(norm)]] = True
        done[idx[(norm < tol_m) & ~sing]] = True
    res = np.linalg.norm(D - predict_d(X, leader, followers, delta, z1, zj), axis=1)
    return GnResult(p=X, converged=done & ~bad, iterations=iters, residual_m=res)


def default_starts(beacons_xy: F64, extra: F64 | None = None) -> F64:
    """Multi-start pattern: the beacons' centroid, rings at 0.5/1/2/4x the array radius, and each beacon."""
    cen = beacons_xy.mean(axis=0)
    rad = max(float(np.max(np.linalg.norm(beacons_xy - cen, axis=1))), 100.0)
    ang = np.linspace(0.0, 2.0 * math.pi, 12, endpoint=False)
    pts = [cen[None, :]]
    for k in (0.5, 1.0, 2.0, 4.0):
        pts.append(cen[None, :] + k * rad * np.column_stack([np.cos(ang), np.sin(ang)]))
    pts.append(beacons_xy + 1.0)
    if extra is not None:
        pts.append(np.asarray(extra, dtype=np.float64).reshape(-1, 2))
    return np.vstack(pts)


def multi_start_solutions(
    d: F64,
    leader: F64,
    followers: F64,
    delta: F64,
    z1: float,
    zj: F64,
    W: F64 | None = None,
    extra_starts: F64 | None = None,
    residual_tol_m: float = 0.1,
    merge_m: float = 1.0,
    **gn: float,
) -> F64:
    """All distinct converged snapshot solutions (n, 2), best residual first (§4.5 ambiguity)."""
    beacons_xy = np.vstack([leader[None, :2], followers[:, :2]])
    starts = default_starts(beacons_xy, extra_starts)
    r = gauss_newton(d, starts, leader, followers, delta, z1, zj, W, **gn)  # type: ignore[arg-type]
    ok = r.converged & (r.residual_m < residual_tol_m)
    cand = r.p[ok]
    res = r.residual_m[ok]
    order = np.argsort(res, kind="stable")
    sols: list[F64] = []
    for i in order:
        if all(np.hypot(*(cand[i] - s)) > merge_m for s in sols):
            sols.append(cand[i])
    return np.array(sols).reshape(-1, 2)
