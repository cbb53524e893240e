"""The modified recurrent-search terrain navigator (digest 001): the pure core with ``step(message)``.

Data flow (Fig. 1 of the paper, §2.10):

    InsSample / RadioAltimeter / BaroAltitude --sync--> (t, x, z, h_ins, h_ra)
      --[1] cell-rate resampler--> cell measurements --[2] groups of N_p--> bank of vertical KFs over the
      hypothesis grid (shared Riccati) --e^2 arrays--> [4/5/6] segmented window F --> [7] argmin + C1..C4
      --> TerrainVerdict, and [8/9] the measurement queue + output formation --> TerrainFix when valid.

Deterministic for a given input order: no wall clock, no randomness. Time comes from ``header.stamp_ns``.
An input that is refused raises :class:`shared.service.InputRejected` and leaves the state untouched.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

from schemas import BaroAltitude, Header, InsSample, Message, NavReset, RadioAltimeter
from schemas.terrain_nav import MAP_HORIZONTAL, VERTICAL_CORRECTION, TerrainFix, TerrainVerdict
from shared.errors import InputRejected
from shared.estimates import gaussian

from . import conditions as cond
from .config import TerrainNavConfig
from .filter import KalmanBank
from .geometry import F64, HypothesisGrid
from .maps import ReferenceMap
from .models import mean_slope, measurement_variance
from .output import cell_centre_terms, grid_covariance, refine
from .resampler import CellMeasurement, CellResampler
from .sync import SyncedSample, Synchroniser
from .window import SegmentedWindow


@dataclass
class FixData:
    """Fix quantities of a valid evaluation (plain numbers; converted to :class:`TerrainFix` by ``step``)."""

    dx_m: float
    dz_m: float
    x_corr_m: float
    z_corr_m: float
    cov_xz_m2: F64
    dh_m: float
    dvh_mps: float
    h_corr_m: float
    vh_corr_mps: float | None
    cov_vert: F64  # [[P_VV, P_Vh], [P_hV, P_hh]]
    refined: bool
    cov_degenerate: bool


@dataclass
class Evaluation:
    """One evaluation of C1-C4 (or a status event when ``state`` is OUT_OF_ZONE, GAP or RESET)."""

    t: float
    state: str
    valid: bool = False
    c1: bool = False
    c2: bool = False
    c3: bool = False
    c4: bool = False
    n_valid: int = 0
    n_measurements: int = 0
    window_span_s: float = 0.0
    f_min_per_n: float | None = None
    d_max: float | None = None
    d_thr: float | None = None
    r_min: int | None = None
    i_star: int | None = None
    j_star: int | None = None
    detail: str = ""
    fix: FixData | None = None

    @property
    def is_status(self) -> bool:
        return self.state in ("OUT_OF_ZONE", "GAP", "RESET")


def verdict_state(c1: bool, c2: bool, c3: bool, c4: bool) -> str:
    """The state word: FIX if all hold, else the first failing condition in the order C1, C2, C3, C4."""
    if not c1:
        return "ACQUIRING"
    if not c2:
        return "NO_FIX_FIT"
    if not c3:
        return "NO_FIX_AMBIGUOUS"
    if not c4:
        return "NO_FIX_UNSTABLE"
    return "FIX"


def _finite(*values: float | None) -> bool:
    return all(v is None or math.isfinite(v) for v in values)


class TerrainNavigator:
    """Recurrent-search terrain navigation over a hypothesis grid with reliability conditions C1-C4.

    ``step(msg)`` takes an :class:`InsSample`, :class:`RadioAltimeter`, :class:`BaroAltitude` or
    :class:`NavReset` and returns the output messages it produced (:class:`TerrainVerdict`, and a
    :class:`TerrainFix` after each valid verdict). ``push_sample`` is the same algorithm from the paper's
    synchronised input tuple on, returning :class:`Evaluation` records (used by the benchmark).
    """

    def __init__(self, ref_map: ReferenceMap, cfg: TerrainNavConfig | None = None, source: str = "") -> None:
        self.cfg = cfg = cfg or TerrainNavConfig()
        self.map = ref_map
        self.source = source
        self.grid = HypothesisGrid(cfg.M_x, cfg.M_z)
        self.zone = ref_map.zone_mask(cfg.M_x, cfg.M_z)
        if not self.zone.any():
            raise ValueError(f"the map {ref_map.shape} has no cell whose {self.grid.shape} hypothesis patch fits")
        self.D1 = ref_map.D1_m2
        self.L_zk = cfg.L_zk_m2 if cfg.L_zk_m2 is not None else ref_map.L_zk(cfg.L_zk_source)
        if cfg.derive_n_limits:
            from .calibration import derive_n_limits

            self.N_min, self.N_max = derive_n_limits(ref_map, cfg)
        else:
            self.N_min, self.N_max = cfg.N_min, cfg.N_max
        self.sync = Synchroniser(cfg.ins_max_gap_s, cfg.baro_max_gap_s, cfg.altitude_source == "baro")
        self.resampler = CellResampler(ref_map.x0_m, ref_map.z0_m, ref_map.cell_m, self.zone, cfg.T_cell_max_s)
        shape = self.grid.shape
        self.bank = KalmanBank(shape, cfg.P0, cfg.phi31, cfg.q_a, cfg.q_h)
        self.window: SegmentedWindow[CellMeasurement] = SegmentedWindow(
            shape, cfg.N_s, self.N_max, cfg.window_recompute_segments
        )
        self._e2: F64 = np.empty(shape)
        self._dem = ref_map.dem
        self.counters: Counter[str] = Counter()
        self._last_t: dict[str, float] = {}
        self._clear_algorithm_state()

    # --- state --------------------------------------------------------------------------------------------
    def _clear_algorithm_state(self) -> None:
        self.bank.reset()
        self.window.reset()
        self.resampler.clear()
        self.group: list[CellMeasurement] = []
        self.argmin_hist: deque[tuple[int, int, int]] = deque()
        self.first_after_gap = True
        self.last_meas: CellMeasurement | None = None
        self.total_meas = 0
        self.n_evaluations = 0
        self._last_ooz_t: float | None = None

    @property
    def F(self) -> F64:
        """The windowed sum of squared residuals over the hypothesis grid (m^2)."""
        return self.window.F

    @property
    def N_valid(self) -> int:
        return self.window.N_valid

    def reset(self, t: float, reason: str = "") -> Evaluation:
        """Clear the window, KF states, argmin history, group and synchroniser; keep the map."""
        self.counters["resets"] += 1
        self.sync.reset()
        self._clear_algorithm_state()
        return Evaluation(t=t, state="RESET", detail=reason[:256])

    # --- message interface ------------------------------------------------------------------------------
    def step(self, msg: Message) -> list[Message]:
        """Consume one input message; return the TerrainVerdict/TerrainFix messages it produced."""
        return self.to_messages(self.step_records(msg))

    def step_records(self, msg: Message) -> list[Evaluation]:
        """As :meth:`step` but returning :class:`Evaluation` records."""
        t = msg.header.stamp_ns * 1e-9
        if isinstance(msg, RadioAltimeter):
            self._check_stamp("ra", t)
            if not _finite(msg.h_agl_m):
                self._reject("non_finite", "radio altimeter height is not finite")
            if not msg.valid:
                self._reject("ra_invalid", "radio-altimeter data-valid flag is false")
            if self.sync.would_drop(t):
                self._reject("unsynchronised", f"no INS sample within {self.cfg.ins_max_gap_s} s of t={t:.3f} s")
            self._last_t["ra"] = t
            return self._push_synced_list(self.sync.add_ra(t, float(msg.h_agl_m)))
        if isinstance(msg, InsSample):
            self._check_stamp("ins", t)
            if not _finite(msg.x_m, msg.z_m, msg.h_m, msg.vx_mps, msg.vz_mps, msg.vh_mps):
                self._reject("non_finite", "INS sample has a non-finite field")
            if not msg.valid:
                self._reject("ins_invalid", "INS valid flag is false")
            self._last_t["ins"] = t
            dropped = self.sync.dropped
            synced, gap = self.sync.add_ins(t, msg.x_m, msg.z_m, msg.h_m, msg.vx_mps, msg.vz_mps, msg.vh_mps)
            lost = self.sync.dropped - dropped
            self.counters["ra_dropped_unsynchronised"] += lost
            out: list[Evaluation] = []
            if gap:
                self.counters["ins_gap"] += 1
                detail = f"INS gap over {self.cfg.ins_max_gap_s} s; {lost} queued RA samples dropped"
                out.append(Evaluation(t=t, state="GAP", detail=detail))
            out.extend(self._push_synced_list(synced))
            return out
        if isinstance(msg, BaroAltitude):
            self._check_stamp("baro", t)
            if not _finite(msg.h_baro_m):
                self._reject("non_finite", "baro altitude is not finite")
            if not msg.valid:
                self._reject("baro_invalid", "baro valid flag is false")
            self._last_t["baro"] = t
            return self._push_synced_list(self.sync.add_baro(t, float(msg.h_baro_m)))
        if isinstance(msg, NavReset):
            return [self.reset(t, msg.reason)]
        raise InputRejected("unsupported_type", type(msg).__name__)

    def _check_stamp(self, stream: str, t: float) -> None:
        last = self._last_t.get(stream)
        if last is not None and t <= last:
            self._reject("stamp_not_increasing", f"{stream} t={t:.9f} s <= last {last:.9f} s")

    def _reject(self, reason: str, detail: str) -> None:
        self.counters[reason] += 1
        raise InputRejected(reason, detail)

    def _push_synced_list(self, samples: list[SyncedSample]) -> list[Evaluation]:
        out: list[Evaluation] = []
        for s in samples:
            out.extend(self.push_sample(s.t, s.x, s.z, s.h_ins, s.h_ra, True, s.v_ground, s.vh))
        return out

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
        if not valid or not _finite(t, x, z, h_ins, h_ra):
            self.counters["samples_discarded"] += 1
            return []
        m, in_zone = self.resampler.push(t, x, z, h_ins, h_ra, True, v_ground, vh)
        if not in_zone:
            self.counters["samples_out_of_zone"] += 1
            self.first_after_gap = True  # re-entry gets post-gap handling
            period = self.cfg.out_of_zone_period_s
            if self._last_ooz_t is None or t - self._last_ooz_t >= period:
                self._last_ooz_t = t
                return [Evaluation(t=t, state="OUT_OF_ZONE", detail="INS position outside the correction zone")]
            return []
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
        if cfg.c3_floor is not None:
            expected = cfg.c3_floor * sum(m.s_expected for m in self.window.measq)
            D = cond.d_max(F, a, b, cfg.mu3, F_min, floor=expected)
        else:
            D = cond.d_max(F, a, b, cfg.mu3, F_min)
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
        if cfg.refine:
            r = refine(measq, ref, cfg, self.D1, dx, dz)
            if r.accepted:
                refined = True
                dx, dz = r.dx_m, r.dz_m
                if r.cov_m2 is not None:
                    cov, degenerate = r.cov_m2, False
        s = self.bank.x[:, a, b]
        P = self.bank.P
        dh, dvh = float(s[2]), float(s[1])
        cov_vert = np.array([[P[1, 1], P[1, 2]], [P[2, 1], P[2, 2]]])
        if cfg.vertical_slope_term:
            # dh is the altitude error at the cell centres: move it to the fix's position and add the slope times
            # the position's uncertainty (models.py)
            g = mean_slope(measq, ref, i_star, j_star)
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

    # --- messages ---------------------------------------------------------------------------------------------
    def _header(self, t: float) -> Header:
        return Header(stamp_ns=max(0, round(t * 1e9)), frame_id=self.cfg.frame_id, source=self.source)

    def verdict_message(self, ev: Evaluation) -> TerrainVerdict:
        cfg = self.cfg
        return TerrainVerdict(
            header=self._header(ev.t),
            state=ev.state,  # type: ignore[arg-type]
            valid=ev.valid,
            c1_enough_data=ev.c1,
            c2_fit=ev.c2,
            c3_unique=ev.c3,
            c4_stable=ev.c4,
            n_valid=ev.n_valid,
            n_min=self.N_min,
            n_max=self.N_max,
            n_measurements=ev.n_measurements,
            window_span_s=ev.window_span_s,
            f_min_per_n_m2=ev.f_min_per_n,
            l_zk_m2=self.L_zk,
            c2_threshold_m2=cfg.mu_F * self.L_zk,
            d_max_cells=ev.d_max,
            d_thr_cells=ev.d_thr,
            r_min_cells=ev.r_min,
            r_thr_cells=cfg.R_thr,
            i_star=ev.i_star,
            j_star=ev.j_star,
            detail=ev.detail,
        )

    def fix_message(self, ev: Evaluation, verdict: TerrainVerdict) -> TerrainFix:
        f = ev.fix
        assert f is not None and ev.i_star is not None and ev.j_star is not None
        return TerrainFix(
            header=verdict.header,
            dx_m=f.dx_m,
            dz_m=f.dz_m,
            estimate=gaussian(self.cfg.frame_id, MAP_HORIZONTAL, [f.x_corr_m, f.z_corr_m], f.cov_xz_m2.tolist()),
            vertical=gaussian(self.cfg.frame_id, VERTICAL_CORRECTION, [f.dvh_mps, f.dh_m], f.cov_vert.tolist()),
            h_corr_m=f.h_corr_m,
            vh_corr_mps=f.vh_corr_mps,
            refined=f.refined,
            cov_degenerate=f.cov_degenerate,
            i_star=ev.i_star,
            j_star=ev.j_star,
            verdict=verdict,
        )

    def to_messages(self, records: list[Evaluation]) -> list[Message]:
        out: list[Message] = []
        for ev in records:
            verdict = self.verdict_message(ev)
            out.append(verdict)
            if ev.fix is not None:
                out.append(self.fix_message(ev, verdict))
        return out
