"""The "base" recurrent-search algorithm of digest §2.13, for the A/B comparison with the modified one.

* runs at the raw synchronised sample rate, reading the map by bilinear interpolation at
  ``(x_ins + i*cell, z_ins + j*cell)`` for every hypothesis (no cell-rate conversion);
* one KF update per sample per hypothesis (N_p = 1), with the same vectorised bank and model;
* a window of individual per-sample e^2 arrays (N_s = 1);
* the minimum is searched after every sample;
* a correction is issued as soon as N_valid reaches N_min, with **no other reliability condition**.

N_min and N_max are the same profile lengths as in the modified algorithm, converted to sample counts
(``cfg.base_n_limits``: ceil(N * f_s * cell / V)). Gap and start handling is the same (first residual after
a start, a gap or a zone re-entry is not accumulated). The fix is ``(i* cell, j* cell)``: the
interpolated map reads are already at the INS position, so no cell-centre term applies.

It is a search component (:mod:`.search`): the navigator's front end (synchronisation, rejection rules, resets,
messages) is the same; ``TerrainNavigator(ref_map, cfg, search=BaseSearch)`` or :func:`BaseRecurrentSearch` runs it.
"""

from __future__ import annotations

import math

import numpy as np

from . import conditions as cond
from .config import TerrainNavConfig
from .core import TerrainNavigator
from .evaluation import Evaluation, FixData, finite
from .filter import KalmanBank
from .maps import ReferenceMap
from .models import measurement_variance
from .output import grid_covariance
from .search import OutOfZone, SearchContext
from .window import SegmentedWindow


class BaseSearch:
    """Per-sample recurrent search with interpolation and the C1-only decision rule (module doc)."""

    def __init__(self, ctx: SearchContext) -> None:
        self.cfg = c = ctx.cfg
        self.out_of_zone = OutOfZone(c.out_of_zone_period_s)
        self.map = ref_map = ctx.map
        self.grid = ctx.grid
        self.D1 = ctx.D1
        self.counters = ctx.counters
        self.N_min, self.N_max = c.base_n_limits(ref_map.cell_m)
        self.base_zone = ref_map.bilinear_zone_mask(c.M_x, c.M_z)
        self.bank = KalmanBank(self.grid.shape, c.P0, c.phi31, c.q_a, c.q_h)
        self.window: SegmentedWindow[None] = SegmentedWindow(
            self.grid.shape, 1, self.N_max, c.window_recompute_segments
        )
        self._R = measurement_variance(1, c.sigma_v_m, c.sigma_map_m, c.c_q, self.D1)
        self._patch = np.empty(self.grid.shape)
        self._dem = ref_map.dem
        self._last_x = 0.0
        self._last_z = 0.0
        self._last_h = 0.0
        self._last_vh: float | None = None
        self.clear()

    def clear(self) -> None:
        """Forget the window, the KF states and the last sample."""
        self.bank.reset()
        self.window.reset()
        self.first_after_gap = True
        self.total_meas = 0
        self.n_evaluations = 0
        self.out_of_zone.reset()
        self._last: tuple[float, float, float] | None = None  # (t, x, z) of the last processed sample

    def push_sample(
        self,
        t: float,
        x: float,
        z: float,
        h_ins: float,
        h_ra: float,
        valid: bool = True,
        v_ground: float = 0.0,
        vh: float | None = None,
    ) -> list[Evaluation]:
        if not valid or not finite(t, x, z, h_ins, h_ra):
            self.counters["samples_discarded"] += 1
            return []
        ref, cfg = self.map, self.cfg
        u = (x - ref.x0_m) / ref.cell_m - 0.5
        v = (z - ref.z0_m) / ref.cell_m - 0.5
        I0 = math.floor(u)
        J0 = math.floor(v)
        n_i, n_j = self.base_zone.shape
        if not (0 <= I0 < n_i and 0 <= J0 < n_j and self.base_zone[I0, J0]):
            self.counters["samples_out_of_zone"] += 1
            self.first_after_gap = True
            return self.out_of_zone.at(t)
        # gap handling (same rules as the modified algorithm, at the sample level)
        if self._last is not None:
            cell_time = ref.cell_m / max(v_ground, cfg.min_speed_mps)
            dt = t - self._last[0]
            if dt > cfg.kappa_gap * cell_time:
                self.first_after_gap = True
            T_reset = (
                cfg.T_reset_s
                if cfg.T_reset_s is not None
                else self.N_max / cfg.base_samples_per_cell(ref.cell_m) * cell_time
            )
            if dt > T_reset:
                self.window.reset()
                self.counters["window_resets"] += 1
        exclude = self.first_after_gap
        self.first_after_gap = False
        self._last = (t, x, z)
        self._last_x, self._last_z, self._last_h, self._last_vh = x, z, h_ins, vh
        # bilinear map reads for every hypothesis: 4 contiguous slices (shared fractional part)
        Mx, Mz = cfg.M_x, cfg.M_z
        fu = u - I0
        fv = v - J0
        A = self._dem[I0 - Mx : I0 + Mx + 2, J0 - Mz : J0 + Mz + 2]
        patch = self._patch
        np.multiply(A[:-1, :-1], (1.0 - fu) * (1.0 - fv), out=patch)
        patch += A[1:, :-1] * (fu * (1.0 - fv))
        patch += A[:-1, 1:] * ((1.0 - fu) * fv)
        patch += A[1:, 1:] * (fu * fv)
        bank = self.bank
        bank.predict(t)
        nu = bank.innovation(patch, h_ra - h_ins)
        if exclude:
            bank.update(nu, self._R)
            self.window.push(None, None)
        else:
            e2 = nu * nu
            Sk = bank.update(nu, self._R)
            if cfg.normalize_by_S:
                e2 *= self._R / Sk
            self.window.push(e2, None)
        self.total_meas += 1
        self.counters["measurements"] += 1
        return [self._evaluate_base(t)]

    def _evaluate_base(self, t: float) -> Evaluation:
        self.n_evaluations += 1
        F = self.window.F
        n_valid = self.window.N_valid
        a, b, F_min = cond.argmin_2d(F)
        i_star, j_star = self.grid.offset_of(a, b)
        c1 = n_valid >= self.N_min  # "as soon as N_valid reaches N_min"
        ev = Evaluation(
            t=t,
            state="FIX" if c1 else "ACQUIRING",
            valid=c1,
            c1=c1,
            c2=True,
            c3=True,
            c4=True,
            n_valid=n_valid,
            n_measurements=self.total_meas,
            f_min_per_n=F_min / n_valid if n_valid > 0 else None,
            i_star=i_star,
            j_star=j_star,
            detail="base algorithm: C2-C4 not evaluated",
        )
        if c1:
            self.counters["fixes"] += 1
            cell = self.map.cell_m
            dx, dz = i_star * cell, j_star * cell
            cov, degenerate = grid_covariance(F, a, b, n_valid, 1.0, cell)
            s = self.bank.x[:, a, b]
            P = self.bank.P
            ev.fix = FixData(
                dx_m=dx,
                dz_m=dz,
                x_corr_m=self._last_x + dx,
                z_corr_m=self._last_z + dz,
                cov_xz_m2=cov,
                dh_m=float(s[2]),
                dvh_mps=float(s[1]),
                h_corr_m=self._last_h + float(s[2]),
                vh_corr_mps=self._last_vh + float(s[1]) if self._last_vh is not None else None,
                cov_vert=np.array([[P[1, 1], P[1, 2]], [P[2, 1], P[2, 2]]]),
                refined=False,
                cov_degenerate=degenerate,
            )
        return ev


def BaseRecurrentSearch(
    ref_map: ReferenceMap, cfg: TerrainNavConfig | None = None, source: str = ""
) -> TerrainNavigator:
    """A navigator whose search is the base algorithm of §2.13."""
    return TerrainNavigator(ref_map, cfg, source, search=BaseSearch)
