"""Block 9: output formation (digest §2.6): cell-centre conversion, covariance and the optional refinement.

* Horizontal: hypothesis (i*, j*) means "while the INS said cell (I_m, J_m) the aircraft was in map cell
  (I_m + i*, J_m + j*)", so the estimate is the matched *cell centre*:
  ``dx = i* cell + mean_m[x0 + (I_m + 1/2) cell - xbar_m]`` (same for z) over the measurements in the window.
* Covariance [D]: a quadratic fitted to F on the 3x3 neighbourhood of the minimum gives the Hessian H
  (m^2 per cell^2); ``Cov_cells = 2 sigma^2 H^-1`` with sigma^2 = F_min/N_valid, plus I/12 for cell
  quantisation when not refined, each sigma floored at cell/sqrt(12), times cell^2. A non-positive-definite
  H (or a minimum on the grid edge) gives the fallback ``((D_thr + 0.5) cell)^2 I`` and ``cov_degenerate``.
* Refinement [P idea, D method]: the stored window profile is replayed through the same 3-state filter over
  sub-cell offsets around the grid estimate with bilinear map reads; the best offset is accepted if its cost
  is not above the cost of the grid estimate recomputed the same way. The replay's filter at the best offset
  also gives dh and dV read at the aircraft's (refined) positions rather than at the cell centres
  (``refine_vertical``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from shared.filters.covariance import symmetrize

from .config import TerrainNavConfig
from .filter import KalmanBank
from .geometry import F64, bilinear
from .maps import ReferenceMap
from .models import measurement_variance
from .resampler import CellMeasurement

# least-squares fit of f = c0 + c1 u + c2 v + c3 u^2 + c4 u v + c5 v^2 on the 3x3 stencil u, v in {-1, 0, 1}
_U, _V = np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0], indexing="ij")
_DESIGN = np.stack([np.ones(9), _U.ravel(), _V.ravel(), _U.ravel() ** 2, (_U * _V).ravel(), _V.ravel() ** 2], axis=1)
_PINV = np.linalg.pinv(_DESIGN)
_READ_ROWS = 8  # measurements per bilinear call of the refinement


def quadratic_hessian(block3x3: F64) -> F64:
    """Hessian [[f_uu, f_uv], [f_uv, f_vv]] of the LS quadratic through a 3x3 block (units per step^2)."""
    c = _PINV @ np.asarray(block3x3, dtype=np.float64).ravel()
    return np.array([[2.0 * c[3], c[4]], [c[4], 2.0 * c[5]]])


def cell_centre_terms(measq: Sequence[CellMeasurement], ref: ReferenceMap) -> tuple[float, float]:
    """Mean over the window of (centre of the INS cell - mean INS position), per axis, m."""
    if not measq:
        return 0.0, 0.0
    cell = ref.cell_m
    cx = sum(ref.x0_m + (m.I + 0.5) * cell - m.x_mean for m in measq) / len(measq)
    cz = sum(ref.z0_m + (m.J + 0.5) * cell - m.z_mean for m in measq) / len(measq)
    return cx, cz


def _pd(H: F64) -> bool:
    return bool(np.all(np.isfinite(H))) and H[0, 0] > 0.0 and float(np.linalg.det(H)) > 0.0


def grid_covariance(
    F: F64, a: int, b: int, n_valid: int, d_thr_cells: float, cell_m: float, refined: bool = False
) -> tuple[F64, bool]:
    """Covariance (m^2) of the grid estimate at array index (a, b) and the degenerate flag (§2.6)."""
    n_i, n_j = F.shape
    fallback = ((d_thr_cells + 0.5) * cell_m) ** 2 * np.eye(2)
    if n_valid <= 0 or a < 1 or b < 1 or a > n_i - 2 or b > n_j - 2:
        return fallback, True
    H = quadratic_hessian(F[a - 1 : a + 2, b - 1 : b + 2])
    if not _pd(H):
        return fallback, True
    sigma2 = max(float(F[a, b]), 0.0) / n_valid
    cov = 2.0 * sigma2 * np.linalg.inv(H)
    cov = symmetrize(cov)
    if not refined:
        cov += np.eye(2) / 12.0
        for k in range(2):  # floor each sigma at one cell / sqrt(12)
            cov[k, k] = max(cov[k, k], 1.0 / 12.0)
    return cov * cell_m * cell_m, False


@dataclass
class Refinement:
    dx_m: float
    dz_m: float
    cost: float
    grid_cost: float
    accepted: bool
    cov_m2: F64 | None
    dh_m: float = 0.0  # the replay filter's dh and dV at the best offset, at the newest measurement
    dvh_mps: float = 0.0
    cov_vert: F64 | None = None  # [[P_VV, P_Vh], [P_hV, P_hh]] of the replay (shared by all offsets)


def refine(
    measq: Sequence[CellMeasurement],
    ref: ReferenceMap,
    cfg: TerrainNavConfig,
    D1_m2: float,
    dx0_m: float,
    dz0_m: float,
) -> Refinement:
    """Replay the window over offsets (dx0, dz0) + (u, v) cell, |u|, |v| <= radius, step ``refine_step_cells``."""
    step = cfg.refine_step_cells
    k = round(cfg.refine_radius_cells / step)
    u = np.arange(-k, k + 1, dtype=np.float64) * step
    U, V = np.meshgrid(u, u, indexing="ij")
    dx = dx0_m + U.ravel() * ref.cell_m
    dz = dz0_m + V.ravel() * ref.cell_m
    bank = KalmanBank(dx.shape, cfg.P0, cfg.phi31, cfg.q_a, cfg.q_h)
    cost = np.zeros(dx.shape)
    used = 0
    # the map reads of _READ_ROWS measurements at a time (elementwise the same arithmetic as one call per
    # measurement, so the same values; blocks this size stay in cache, whole-window arrays were slower)
    measq = list(measq)
    e2 = np.empty(dx.shape)
    for lo in range(0, len(measq), _READ_ROWS):
        block = measq[lo : lo + _READ_ROWS]
        xm = np.fromiter((m.x_mean for m in block), dtype=np.float64, count=len(block))
        zm = np.fromiter((m.z_mean for m in block), dtype=np.float64, count=len(block))
        ui = (xm[:, None] + dx[None, :] - ref.x0_m) / ref.cell_m - 0.5
        vi = (zm[:, None] + dz[None, :] - ref.z0_m) / ref.cell_m - 0.5
        reads = bilinear(ref.dem, ui, vi)
        for row, m in enumerate(block):
            bank.predict(m.t)
            R = measurement_variance(m.n, cfg.sigma_v_m, cfg.sigma_map_m, cfg.c_q, D1_m2)
            nu = bank.innovation(reads[row], m.h_ra - m.h_ins)
            if lo + row > 0 and not m.exclude:
                np.multiply(nu, nu, out=e2)
                cost += e2
                used += 1
            bank.update(nu, R)
    centre = k * (2 * k + 1) + k
    best = int(np.nanargmin(cost))
    grid_cost = float(cost[centre])
    accepted = bool(cost[best] <= grid_cost) and used > 0
    cov = None
    C = cost.reshape(U.shape)
    a, b = divmod(best, 2 * k + 1)
    if accepted and 1 <= a <= 2 * k - 1 and 1 <= b <= 2 * k - 1:
        H = quadratic_hessian(C[a - 1 : a + 2, b - 1 : b + 2]) / (step * step)
        if _pd(H):
            sigma2 = max(float(cost[best]), 0.0) / used
            cov_cells = 2.0 * sigma2 * np.linalg.inv(H)
            cov_cells = symmetrize(cov_cells) + np.eye(2) * (step * step / 12.0)
            # the offset drifts with the horizontal velocity error over the window: the estimate belongs to
            # about the middle of the window, the fix to its newest measurement
            span = measq[-1].t - measq[0].t if measq else 0.0
            drift = cfg.sigma_Vh_expected_mps * 0.5 * span / ref.cell_m
            cov_cells += np.eye(2) * drift * drift
            floor = cfg.refine_sigma_floor_cells**2
            for i in range(2):
                cov_cells[i, i] = max(cov_cells[i, i], floor)
            cov = cov_cells * ref.cell_m**2
    P = bank.P
    return Refinement(
        float(dx[best]),
        float(dz[best]),
        float(cost[best]),
        grid_cost,
        accepted,
        cov,
        dh_m=float(bank.x[2, best]),
        dvh_mps=float(bank.x[1, best]),
        cov_vert=np.array([[P[1, 1], P[1, 2]], [P[2, 1], P[2, 2]]]),
    )
