"""The terrain navigator (digest 001): the pure core with ``step(message)``, a front end over a search component.

    InsSample / RadioAltimeter / BaroAltitude --sync--> (t, x, z, h_ins, h_ra) --search--> Evaluation records
      --> TerrainVerdict, and TerrainFix when valid.

The navigator owns what both algorithm variants share: synchronisation, the rejection rules, resets and the
output messages. The search is a component (:mod:`.search`): :class:`~.modified_algorithm.ModifiedSearch` (the
default, digest §2) or :class:`~.base_algorithm.BaseSearch` (§2.13, the A/B reference), passed as ``search=``.

Deterministic for a given input order: no wall clock, no randomness. Time comes from ``header.stamp_ns``.
An input that is refused raises :class:`shared.service.InputRejected` and leaves the state untouched.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from schemas import BaroAltitude, Header, InsSample, Message, NavReset, RadioAltimeter
from schemas.terrain_nav import MAP_HORIZONTAL, VERTICAL_CORRECTION, TerrainFix, TerrainVerdict
from shared.errors import InputRejected
from shared.estimates import gaussian

from .config import TerrainNavConfig
from .evaluation import Evaluation, FixData, verdict_state
from .evaluation import finite as _finite
from .filter import KalmanBank
from .geometry import F64, HypothesisGrid
from .maps import ReferenceMap
from .modified_algorithm import ModifiedSearch
from .search import RecurrentSearch, SearchContext, SearchFactory
from .sync import SyncedSample, Synchroniser
from .window import SegmentedWindow

__all__ = ["Evaluation", "FixData", "TerrainNavigator", "verdict_state"]


class TerrainNavigator:
    """Recurrent-search terrain navigation over a hypothesis grid with reliability conditions C1-C4.

    ``step(msg)`` takes an :class:`InsSample`, :class:`RadioAltimeter`, :class:`BaroAltitude` or
    :class:`NavReset` and returns the output messages it produced (:class:`TerrainVerdict`, and a
    :class:`TerrainFix` after each valid verdict). ``push_sample`` is the same algorithm from the paper's
    synchronised input tuple on, returning :class:`Evaluation` records (used by the benchmark). ``search``
    builds the search component (default: the modified algorithm of §2).
    """

    def __init__(
        self,
        ref_map: ReferenceMap,
        cfg: TerrainNavConfig | None = None,
        source: str = "",
        search: SearchFactory | None = None,
    ) -> None:
        self.cfg = cfg = cfg or TerrainNavConfig()
        self.map = ref_map
        self.source = source
        self.grid = HypothesisGrid(cfg.M_x, cfg.M_z)
        self.zone = ref_map.zone_mask(cfg.M_x, cfg.M_z)
        if not self.zone.any():
            raise ValueError(f"the map {ref_map.shape} has no cell whose {self.grid.shape} hypothesis patch fits")
        self.D1 = ref_map.D1_m2
        self.L_zk = cfg.L_zk_m2 if cfg.L_zk_m2 is not None else ref_map.L_zk(cfg.L_zk_source)
        self.sync = Synchroniser(cfg.ins_max_gap_s, cfg.baro_max_gap_s, cfg.altitude_source == "baro")
        self.counters: Counter[str] = Counter()
        self._last_t: dict[str, float] = {}
        ctx = SearchContext(ref_map, cfg, self.grid, self.zone, self.D1, self.L_zk, self.counters)
        self.search: RecurrentSearch = (search or ModifiedSearch)(ctx)

    # --- the search's state, as the navigator's --------------------------------------------------------------
    @property
    def bank(self) -> KalmanBank:
        return self.search.bank

    @property
    def window(self) -> SegmentedWindow[Any]:
        return self.search.window

    @property
    def F(self) -> F64:
        """The windowed sum of squared residuals over the hypothesis grid (m^2)."""
        return self.search.window.F

    @property
    def N_valid(self) -> int:
        return self.search.window.N_valid

    @property
    def N_min(self) -> int:
        return self.search.N_min

    @property
    def N_max(self) -> int:
        return self.search.N_max

    @property
    def total_meas(self) -> int:
        return self.search.total_meas

    @property
    def n_evaluations(self) -> int:
        return self.search.n_evaluations

    def reset(self, t: float, reason: str = "") -> Evaluation:
        """Clear the search (window, KF states, memories) and the synchroniser; keep the map."""
        self.counters["resets"] += 1
        self.sync.reset()
        self.search.clear()
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
        push = self.search.push_sample
        for s in samples:
            out.extend(push(s.t, s.x, s.z, s.h_ins, s.h_ra, True, s.v_ground, s.vh))
        return out

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
        return self.search.push_sample(t, x, z, h_ins, h_ra, valid, v_ground, vh)

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
