"""Single-cycle error bound of a beacon set *with its leader and reply order*, full error budget (digest §4.2, §4.6).

For a receiver at p (depth z) and an ordered set (leader A1, followers A2..A(M+1) in reply slots tau_2..), one cycle
gives the range differences d_j = rho_j - rho_1 with Jacobian rows H_j = (u_j - u_1)_xy (u: unit vector beacon ->
receiver) and the noise covariance of §4.2, in metres^2:

    R = c^2 [sigma_t^2 (I + 1 1^T) + sigma_f^2 I]      arrival time (the leader's is shared), reply jitter
      + (sigma_c / c)^2 s s^T                           sound speed: a scale error on s_j = r_1j + rho_j - rho_1
      + sigma_node^2 (g g^T + diag(|h_j|^2))            node (g_j = e(A1->X) - e(A1->Aj), h_j = e(A1->Aj) - e(Aj->X))
      + sigma_v^2 dt_j dt_k (u_j . u_k)_xy              DR velocity error over dt_j (dt_j = tau_j + s_j/c)

and the bound P = (H^T R^-1 H)^-1, DRMS = sqrt(tr P). With arrival-time noise only the DRMS does not depend on the
leader (T-MM-7); every other term does: the sound-speed term through s_j (small when the leader is far from the
receiver on the far side of the followers, 2 r_1j when it is next to it), reply jitter and the node term through
which beacons are differenced, the motion term through the slot order. Everything is vectorised over (variant,
point); a variant is one ordered set.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .registry import F64

I64 = NDArray[np.int64]


def _units(pos: F64, points: F64) -> tuple[F64, F64]:
    """Unit vectors beacon -> point (B, P, 3) and ranges (B, P)."""
    d = points[None, :, :] - pos[:, None, :]
    rng = np.sqrt(np.sum(d * d, axis=2))
    return d / np.maximum(rng, 1e-9)[:, :, None], rng


def drms_full(
    pos: F64,
    points: F64,
    leaders: I64,
    followers: I64,
    tau_s: F64,
    c_mps: float,
    sigma_t_s: float,
    sigma_f_s: float = 0.0,
    sigma_c_mps: float = 0.0,
    sigma_node_m: float = 0.0,
    sigma_v_mps: float = 0.0,
) -> F64:
    """DRMS (V, P) of every ordered set (``leaders`` (V,), ``followers`` (V, M) in slot order) at every point."""
    u, rho = _units(pos, points)
    uL = u[leaders]  # (V, P, 3)
    uF = np.moveaxis(u[followers], 1, 2)  # (V, P, M, 3)
    H = (uF - uL[:, :, None, :])[..., :2]  # (V, P, M, 2)
    M = followers.shape[1]
    r1j = np.linalg.norm(pos[followers] - pos[leaders][:, None, :], axis=2)  # (V, M)
    s = r1j[:, None, :] + np.moveaxis(rho[followers], 1, 2) - rho[leaders][:, :, None]  # (V, P, M)
    eye = np.eye(M)
    R = np.broadcast_to(c_mps**2 * (sigma_t_s**2 * (eye + 1.0) + sigma_f_s**2 * eye), (*s.shape, M)).copy()
    if sigma_c_mps > 0.0:
        k = sigma_c_mps / c_mps
        R += k * k * s[..., :, None] * s[..., None, :]
    if sigma_node_m > 0.0:
        e1j = pos[followers] - pos[leaders][:, None, :]
        e1j = e1j / np.maximum(np.linalg.norm(e1j, axis=2), 1e-9)[:, :, None]  # (V, M, 3)
        g = uL[:, :, None, :] - e1j[:, None, :, :]  # (V, P, M, 3)
        h = e1j[:, None, :, :] - uF
        R += sigma_node_m**2 * (np.einsum("vpmi,vpni->vpmn", g, g) + np.einsum("vpmi,vpmi->vpm", h, h)[..., None] * eye)
    if sigma_v_mps > 0.0:
        dt = tau_s[None, None, :M] + s / c_mps
        uu = np.einsum("vpmi,vpni->vpmn", uF[..., :2], uF[..., :2])
        R += sigma_v_mps**2 * dt[..., :, None] * dt[..., None, :] * uu
    with np.errstate(all="ignore"):
        Rinv_H = _solve(R, H)
        F = np.einsum("vpmi,vpmj->vpij", H, Rinv_H)
    fxx, fxy, fyy = F[..., 0, 0], F[..., 0, 1], F[..., 1, 1]
    det = fxx * fyy - fxy * fxy
    ok = np.isfinite(det) & (det > 1e-12 * (fxx + fyy) ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        tr = (fxx + fyy) / np.where(ok, det, 1.0)
    return np.where(ok & (tr >= 0.0), np.sqrt(np.abs(tr)), np.inf)


def _solve(R: F64, H: F64) -> F64:
    """R^-1 H for a batch; a singular or non-finite R (e.g. a beacon 1e12 m away) gives NaN there, not an error."""
    bad = np.asarray(~np.isfinite(R).all(axis=(-1, -2)))
    Rs = np.where(bad[..., None, None], np.eye(R.shape[-1]), R)
    try:
        X = np.linalg.solve(Rs, H)
    except np.linalg.LinAlgError:
        X = np.empty_like(H)
        flat_R, flat_H, flat_X = (
            Rs.reshape(-1, *R.shape[-2:]),
            H.reshape(-1, *H.shape[-2:]),
            X.reshape(-1, *H.shape[-2:]),
        )
        for i in range(flat_R.shape[0]):
            try:
                flat_X[i] = np.linalg.solve(flat_R[i], flat_H[i])
            except np.linalg.LinAlgError:
                flat_X[i] = np.nan
    X[bad] = np.nan
    return X


def schedule_fits(
    pos: F64,
    points: F64,
    leaders: I64,
    followers: I64,
    tau_s: F64,
    c_mps: float,
    cycle_period_s: float,
    t_pkt_s: float,
    guard_s: float,
) -> NDArray[np.bool_]:
    """(V,) True where, at every point, every reply has arrived (and ended) before the next leader packet (§4.9):
    r_1j/c + tau_j + rho_j/c + T_pkt + g <= T_c + rho_1/c."""
    _, rho = _units(pos, points)
    M = followers.shape[1]
    r1j = np.linalg.norm(pos[followers] - pos[leaders][:, None, :], axis=2)  # (V, M)
    last = (r1j[:, None, :] + np.moveaxis(rho[followers], 1, 2)) / c_mps + tau_s[None, None, :M]  # (V, P, M)
    ok = last.max(axis=2) + t_pkt_s + guard_s <= cycle_period_s + rho[leaders] / c_mps
    return np.asarray(ok.all(axis=1))
