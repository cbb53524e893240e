"""The exact posterior over the hypothesis grid from a window of cell measurements (an independent reference).

Used to score the reliability conditions: it is a batch computation, written from the measurement model,
not from the recursive filter bank.

Model (digest §1.4, §1.5, §2.2): for hypothesis (i, j) and cell measurement k of the window,

    y_ij(k) = H_ij(k) + h_ra(k) - h_ins(k) = dh(t_k) + n_k,
    dh(t) = dh0 + dV0 (t - t_1) + da (t - t_1)^2 / 2,    theta = (da, dV0, dh0) ~ N(0, P0),
    n_k ~ N(0, R_k) independent,  R_k = sigma_v^2 / n_k + sigma_map^2 + c_q D1.

So y_ij ~ N(0, C) with C = A P0 A^T + diag(R) (A: rows [(t-t_1)^2/2, t-t_1, 1]), the **same C for every
hypothesis** (the process noise q_a, 1e-6 (m/s^2)^2/s, is left out). With a uniform prior over the grid,

    p(ij | y) ∝ exp(-1/2 y_ij^T C^-1 y_ij),

computed for all hypotheses at once with one Cholesky factor of C (N x N, N <= the window length).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from .config import TerrainNavConfig
from .geometry import F64
from .maps import ReferenceMap
from .models import measurement_variance
from .resampler import CellMeasurement


@dataclass(frozen=True)
class Posterior:
    """Posterior probabilities over the (2M_x+1, 2M_z+1) grid of offsets and its summary."""

    p: F64
    M_x: int
    M_z: int

    @property
    def argmax(self) -> tuple[int, int]:
        """Offset (i, j) in cells of the most probable hypothesis."""
        a, b = np.unravel_index(int(np.argmax(self.p)), self.p.shape)
        return int(a) - self.M_x, int(b) - self.M_z

    def mass_within(self, i: int, j: int, radius_cells: float = 1.0) -> float:
        """Posterior probability of the offsets within ``radius_cells`` (Chebyshev) of (i, j)."""
        a, b = i + self.M_x, j + self.M_z
        r = int(np.floor(radius_cells))
        return float(self.p[max(a - r, 0) : a + r + 1, max(b - r, 0) : b + r + 1].sum())

    def decisive(self, level: float = 0.99) -> bool:
        """True if at least ``level`` of the mass lies within one cell of the most probable offset."""
        i, j = self.argmax
        return self.mass_within(i, j) >= level


def exact_posterior(
    window: Sequence[CellMeasurement], ref: ReferenceMap, cfg: TerrainNavConfig, D1_m2: float | None = None
) -> Posterior:
    """The exact posterior over the offsets from the cell measurements ``window`` (all of them are used)."""
    if not window:
        raise ValueError("no measurement")
    Mx, Mz = cfg.M_x, cfg.M_z
    D1 = ref.D1_m2 if D1_m2 is None else D1_m2
    t = np.array([m.t for m in window]) - window[0].t
    A = np.column_stack([0.5 * t * t, t, np.ones_like(t)])
    P0 = np.diag(cfg.P0)
    R = np.array([measurement_variance(m.n, cfg.sigma_v_m, cfg.sigma_map_m, cfg.c_q, D1) for m in window])
    C = A @ P0 @ A.T + np.diag(R)
    Y = np.stack(
        [ref.dem[m.I - Mx : m.I + Mx + 1, m.J - Mz : m.J + Mz + 1] + (m.h_ra - m.h_ins) for m in window]
    ).reshape(len(window), -1)
    quad = np.einsum("kh,kh->h", Y, cho_solve(cho_factor(C), Y))
    log_p = -0.5 * (quad - quad.min())
    p = np.exp(log_p)
    p /= p.sum()
    return Posterior(p.reshape(2 * Mx + 1, 2 * Mz + 1), Mx, Mz)
