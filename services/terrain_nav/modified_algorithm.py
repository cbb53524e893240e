"""The modified recurrent search of digest §2 (the navigator's default search component).

Data flow (Fig. 1 of the paper, §2.10), from a synchronised sample on:

    (t, x, z, h_ins, h_ra) --[1] cell-rate resampler--> cell measurements --[2] groups of N_p--> bank of vertical
      KFs over the hypothesis grid (shared Riccati) --e^2 arrays--> [4/5/6] segmented window F --> [7] argmin +
      C1..C4 --> the verdict, and [8/9] the measurement queue + output formation --> the fix when valid.

Deterministic for a given input order: no wall clock, no randomness.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from . import conditions as cond
from .evaluation import Evaluation, FixData, finite, verdict_state
from .filter import KalmanBank
from .geometry import F64
from .models import mean_slope, measurement_variance
from .output import cell_centre_terms, grid_covariance, refine
from .resampler import CellMeasurement, CellResampler
from .search import OutOfZone, SearchContext
from .window import SegmentedWindow


class ModifiedSearch:
    """Cell-rate recurrent search with the reliability conditions C1-C4 (module doc)."""

    def __init__(self, ctx: SearchContext) -> None:
        self.cfg = cfg = ctx.cfg
        self.out_of_zone = OutOfZone(cfg.out_of_zone_period_s)
        self.map = ref_map = ctx.map
        self.grid = ctx.grid
        self.zone = ctx.zone
        self.D1 = ctx.D1
        self.L_zk = ctx.L_zk
        self.counters = ctx.counters
        if cfg.derive_n_limits:
            from .calibration import derive_n_limits

            self.N_min, self.N_max = derive_n_limits(ref_map, cfg)
        else:
            self.N_min, self.N_max = cfg.N_min, cfg.N_max
        self.resampler = CellResampler(ref_map.x0_m, ref_map.z0_m, ref_map.cell_m, self.zone, cfg.T_cell_max_s)
        shape = self.grid.shape
        self.bank = KalmanBank(shape, cfg.P0, cfg.phi31, cfg.q_a, cfg.q_h)
        self.window: SegmentedWindow[CellMeasurement] = SegmentedWindow(
            shape, cfg.N_s, self.N_max, cfg.window_recompute_segments
        )
        self._e2: F64 = np.empty(shape)
        self._dem = ref_map.dem
        self.clear()

    def clear(self) -> None:
        """Forget the window, the KF states, the argmin history, the group and the resampler's cell."""
        self.bank.reset()
        self.window.reset()
        self.resampler.clear()
        self.group: list[CellMeasurement] = []
        self.argmin_hist: deque[tuple[int, int, int]] = deque()
        self.first_after_gap = True
        self.last_meas: CellMeasurement | None = None
        self.total_meas = 0
        self.n_evaluations = 0
        self.out_of_zone.reset()

    # --- block 1: cell-rate conversion ------------------------------------------------------------------------
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
        """One synchronised sample ``(t, x_ins, z_ins, h_ins, h_ra, i_ra)`` (plus ground/vertical speed)."""
        if not valid or not finite(t, x, z, h_ins, h_ra):
            self.counters["samples_discarded"] += 1
            return []
        m, in_zone = self.resampler.push(t, x, z, h_ins, h_ra, True, v_ground, vh)
        if not in_zone:
            self.counters["samples_out_of_zone"] += 1
            self.first_after_gap = True  # re-entry gets post-gap handling
            return self.out_of_zone.at(t)
        return self.push_measurement(m) if m is not None else []

    # --- block 2: gap handling and grouping -------------------------------------------------------------------
    def push_measurement(self, m: CellMeasurement) -> list[Evaluation]:
        """One cell-rate measurement: gap detection, exclusion flag, grouping; evaluates on a full group."""
        cfg = self.cfg
        self.counters["measurements"] += 1
        last = self.last_meas
        if last is not None:
            v = max(m.v_ground, cfg.min_speed_mps)
            cell_time = self.map.cell_m / v
            jump = max(abs(m.I - last.I), abs(m.J - last.J))
            dt = m.t - last.t
            if jump > 1 or dt > cfg.kappa_gap * cell_time:
                self.first_after_gap = True
            T_reset = cfg.T_reset_s if cfg.T_reset_s is not None else self.N_max * cell_time
            if dt > T_reset:
                m.reset_before = True
        m.exclude = self.first_after_gap
        if m.exclude:
            self.counters["excluded_residuals"] += 1
        self.first_after_gap = False
        self.last_meas = m
        self.group.append(m)
        if len(self.group) < cfg.N_p:
            return []
        self.process_group(self.group)
        self.group = []
        return [self.evaluate()]

    # --- bank of KFs + window ----------------------------------------------------------------------------------
    def process_group(self, group: list[CellMeasurement]) -> None:
        """Run the KF bank over a group, measurement by measurement, and push the e^2 arrays into the window."""
        cfg = self.cfg
        Mx, Mz = cfg.M_x, cfg.M_z
        bank, window, e2 = self.bank, self.window, self._e2
        for m in group:
            if m.reset_before:
                self.counters["window_resets"] += 1
                window.reset()
                self.argmin_hist.clear()
            bank.predict(m.t)
            patch = self._dem[m.I - Mx : m.I + Mx + 1, m.J - Mz : m.J + Mz + 1]  # contiguous slice (S1)
            R = measurement_variance(m.n, cfg.sigma_v_m, cfg.sigma_map_m, cfg.c_q, self.D1)
            nu = bank.innovation(patch, m.h_ra - m.h_ins)
            if cfg.pre_gate_k is not None and window.N_valid > self.N_min:
                # optional innovation gate on the leading hypothesis (argmin of F) [D], off by default
                a, b, _ = cond.argmin_2d(window.F)
                if abs(float(nu[a, b])) > cfg.pre_gate_k * math.sqrt(bank.innovation_variance(R)):
                    self.counters["gated"] += 1
                    window.push(None, m)
                    self.total_meas += 1
                    continue
            if m.exclude:
                Sk = bank.update(nu, R)
                window.push(None, m)
            else:
                np.multiply(nu, nu, out=e2)
                Sk = bank.update(nu, R)
                m.s_expected = Sk
                if cfg.normalize_by_S:
                    e2 *= R / Sk
                    m.s_expected = R
                window.push(e2, m)
            self.total_meas += 1

    # --- block 7: extremum + reliability ------------------------------------------------------------------------
    def evaluate(self) -> Evaluation:
        """Argmin of F and the conditions C1-C4; the fix (block 9) when all hold."""
        cfg = self.cfg
        self.n_evaluations += 1
        self.counters["evaluations"] += 1
        F = self.window.F
        n_valid = self.window.N_valid
        a, b, F_min = cond.argmin_2d(F)
        i_star, j_star = self.grid.offset_of(a, b)
        hist = self.argmin_hist
        hist.append((self.total_meas, i_star, j_star))
        while hist and hist[0][0] <= self.total_meas - cfg.N_R - cfg.N_p:
            hist.popleft()
        c1 = cond.c1_enough_data(n_valid, self.N_min, cfg.c1_strict)
        c2 = cond.c2_fit(F_min, n_valid, cfg.mu_F, self.L_zk)
        beyond = cfg.c3_evidence_beyond_cells
        cap = (
            None
            if cfg.c3_evidence is None
            else cond.evidence_gap(cfg.c3_evidence, [m.s_expected for m in self.window.measq], F_min, n_valid)
        )
        if cfg.c3_floor is not None:
            expected = cfg.c3_floor * sum(m.s_expected for m in self.window.measq)
            D = cond.d_max(F, a, b, cfg.mu3, F_min, floor=expected, gap_cap=cap, cap_beyond=beyond)
        else:
            D = cond.d_max(F, a, b, cfg.mu3, F_min, gap_cap=cap, cap_beyond=beyond)
        D_thr = cond.d_threshold(n_valid, self.N_min, self.N_max, cfg.mu1, cfg.mu2, cfg.phi)
        c3 = cond.c3_unique(D, D_thr)
        R = cond.r_min(hist, self.total_meas, cfg.N_R)
        c4 = cond.c4_stable(R, cfg.R_thr, cfg.R_strict)
        valid = c1 and c2 and c3 and c4
        measq = self.window.measq
        newest = measq[-1]
        ev = Evaluation(
            t=newest.t,
            state=verdict_state(c1, c2, c3, c4),
            valid=valid,
            c1=c1,
            c2=c2,
            c3=c3,
            c4=c4,
            n_valid=n_valid,
            n_measurements=self.total_meas,
            window_span_s=max(newest.t - measq[0].t, 0.0),
            f_min_per_n=F_min / n_valid if n_valid > 0 else None,
            d_max=D,
            d_thr=D_thr,
            r_min=R,
            i_star=i_star,
            j_star=j_star,
        )
        if valid:
            self.counters["fixes"] += 1
            ev.fix = self._make_fix(a, b, i_star, j_star, D_thr, n_valid)
        return ev

    def _make_fix(self, a: int, b: int, i_star: int, j_star: int, D_thr: float, n_valid: int) -> FixData:
        cfg, ref = self.cfg, self.map
        measq = self.window.measq
        newest = measq[-1]
        cx, cz = cell_centre_terms(measq, ref) if cfg.cell_centre_conversion else (0.0, 0.0)
        dx = i_star * ref.cell_m + cx
        dz = j_star * ref.cell_m + cz
        cov, degenerate = grid_covariance(self.window.F, a, b, n_valid, D_thr, ref.cell_m)
        dx0, dz0 = dx, dz
        refined = False
        s = self.bank.x[:, a, b]
        P = self.bank.P
        dh, dvh = float(s[2]), float(s[1])
        cov_vert = np.array([[P[1, 1], P[1, 2]], [P[2, 1], P[2, 2]]])
        at_position = False  # dh read at the fix's position (the refinement's replay) rather than the centres
        if cfg.refine:
            r = refine(measq, ref, cfg, self.D1, dx, dz)
            if r.accepted:
                refined = True
                dx, dz = r.dx_m, r.dz_m
                if r.cov_m2 is not None:
                    cov, degenerate = r.cov_m2, False
                if cfg.refine_vertical and r.cov_vert is not None:
                    dh, dvh, cov_vert, at_position = r.dh_m, r.dvh_mps, r.cov_vert, True
        if cfg.vertical_slope_term:
            # the grid filter's dh is the altitude error at the cell centres: move it to the fix's position; either
            # way add the slope times the position's uncertainty (models.py)
            g = mean_slope(measq, ref, i_star, j_star)
            if not at_position:
                dh += float(g[0] * (dx - dx0) + g[1] * (dz - dz0))
            cov_vert[1, 1] += float(g @ cov @ g)
        return FixData(
            dx_m=dx,
            dz_m=dz,
            x_corr_m=newest.x_mean + dx,
            z_corr_m=newest.z_mean + dz,
            cov_xz_m2=cov,
            dh_m=dh,
            dvh_mps=dvh,
            h_corr_m=newest.h_ins + dh,
            vh_corr_mps=newest.vh_ins + dvh if newest.vh_ins is not None else None,
            cov_vert=cov_vert,
            refined=refined,
            cov_degenerate=degenerate,
        )
