"""The pure core of the LBL estimator (digest 000): ``LblNavCore.step(message) -> list of output messages``.

No I/O and no wall clock: time comes from ``header.stamp_ns`` of the inputs. Inputs are the schemas'
``BeaconRange``, ``SpeedLog``, ``Heading``, ``Depth``, ``Current``, ``BeaconTable`` and ``NavReset``. The core
runs on a fixed epoch grid (``dt_s``); an epoch closes when an input stamped later than the epoch plus
``reorder_latency_s`` arrives (or on ``flush``), and every closed epoch yields one ``LblFix`` (plus ``LblEvent``
messages). A refused input raises ``shared.service.InputRejected(reason, detail)`` before any state change.

Lifecycle (5.3): WAITING -> BUFFERING -> LAUNCH/UNIQUE -> AMBIGUOUS -> RESOLVED/MERGED -> TRACKING <-> DR_ONLY.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
from pydantic import BaseModel

from schemas import (
    BeaconRange,
    BeaconTable,
    Current,
    Depth,
    Header,
    Heading,
    Hypothesis,
    Message,
    NavReset,
    SpeedLog,
)
from schemas.estimate import GaussianEstimate
from schemas.lbl_nav import LBL_STATE, LblEvent, LblFix
from shared.errors import InputRejected
from shared.estimates import POSITION, gaussian
from shared.models import built

from . import initiation
from .config import LblNavConfig
from .epochs import NS, DrIntegrator
from .filter import BufferedEpoch, HypothesisBank, HypothesisFilter, StepReport
from .models import IDC, IDK, IUE, IUN, IX, IY, DrInterval, MotionModel, RangeRow, Row

M = TypeVar("M", bound=BaseModel)

#: per model: its non-factory defaults, its number of fields, and whether it has a post-init hook
_MODEL_INFO: dict[type, tuple[dict[str, Any], int, bool]] = {}


def _model_info(cls: type[BaseModel]) -> tuple[dict[str, Any], int, bool]:
    """Non-factory defaults of a model (factory fields are always passed explicitly by the core), its number of
    fields and whether it has a post-init hook (class attributes read once: the hot path is a dict lookup)."""
    info = _MODEL_INFO.get(cls)
    if info is None:
        fields = cls.model_fields
        d = {n: f.default for n, f in fields.items() if not f.is_required() and f.default_factory is None}
        info = _MODEL_INFO[cls] = (d, len(fields), cls.__pydantic_post_init__ is not None)
    return info


def _construct(cls: type[M], kw: dict[str, Any]) -> M:
    """``cls.model_construct(**defaults, **kw)`` without its per-field loop (a fifth of its cost): every field of
    the model is given (the non-factory defaults merged in), so the instance is the one model_construct builds —
    the same ``__dict__`` and fields set, no extra, no private attributes: :func:`shared.models.built`)."""
    defaults, n_fields, post_init = _model_info(cls)
    values = {**defaults, **kw}
    if len(values) != n_fields or post_init:
        return cls.model_construct(**values)
    return built(cls, values)


#: [IMPL] physically possible values of the DR inputs (m/s, m); anything beyond is refused before use, so that a
#: finite but absurd value (1e150 m of depth) cannot overflow the filters. Headings are any finite angle.
_PHYSICAL_LIMITS: dict[str, tuple[float, float]] = {
    "SpeedLog": (-50.0, 50.0),
    "Depth": (-100.0, 12_000.0),
    "Current": (-20.0, 20.0),
}


@dataclass(frozen=True)
class _Range:
    beacon_id: str
    y_m: float
    T_s: float
    stamp_ns: int


class LblNavCore:
    """One vehicle's estimator. ``step`` is deterministic for a given input order."""

    def __init__(self, cfg: LblNavConfig, table: BeaconTable | None = None) -> None:
        self.cfg = cfg
        self.motion = MotionModel(cfg)
        self.dt_ns = round(cfg.dt_s * NS)
        self.off_ns = round(cfg.epoch_offset_s * NS)
        self.lat_ns = round(cfg.reorder_latency_s * NS)
        self.tol_ns = round(cfg.epoch_tolerance_s * NS)
        self.beacons: dict[str, tuple[float, float, float]] = {
            b.beacon_id: (b.x_east_m, b.y_north_m, b.depth_m) for b in cfg.beacons
        }
        if table is not None:
            self._set_table(table)
        self.dr = DrIntegrator(cfg)
        self.depth_m: float | None = None
        self._last: dict[str, int] = {}
        self._next_k: int | None = None
        self._open: dict[int, dict[str, _Range]] = {}
        self.buffer_dropped = 0
        self._sd2 = cfg.sigma_depth_m**2
        self._validate = cfg.validate_outputs
        self._frame_id = cfg.frame_id
        self._log10_threshold = math.log10(cfg.ratio_threshold)
        self._reset_estimation()

    # ------------------------------------------------------------------------------------------------------------
    def _reset_estimation(self) -> None:
        self.state = "WAITING"
        self.buffer: list[BufferedEpoch] = []
        self.bank: HypothesisBank | None = None
        self.k0: int | None = None
        self.launch_stamp_ns: int | None = None
        self.resolved_stamp_ns: int | None = None
        self.source: str | None = None
        self.accepted: int | None = None
        self.last_range_used_ns: int | None = None
        self._consec_rejected = 0
        self._overflowing = False
        self._rr_last: dict[str, tuple[int, float]] = {}
        self._rr_rej: dict[str, tuple[int, float]] = {}
        self._decision_lr: float | None = None
        self._in_gap = False

    def _set_table(self, table: BeaconTable) -> None:
        ids = [b.beacon_id for b in table.beacons]
        if len(ids) != len(set(ids)):
            raise InputRejected("bad_beacon_table", "duplicate beacon ids")
        for b in table.beacons:
            if not all(math.isfinite(v) for v in (b.x_east_m, b.y_north_m, b.depth_m)):
                raise InputRejected("non_finite", f"beacon {b.beacon_id}")
        self.beacons = {b.beacon_id: (b.x_east_m, b.y_north_m, b.depth_m) for b in table.beacons}

    def t_ns(self, k: int) -> int:
        return self.off_ns + k * self.dt_ns

    # ---- public API --------------------------------------------------------------------------------------------
    def step(self, msg: Message) -> list[Message]:
        """Consume one input message; returns the outputs of the epochs it closed (LblFix, LblEvent)."""
        if isinstance(msg, BeaconTable):
            self._set_table(msg)
            return []
        if isinstance(msg, NavReset):
            return self._reset(msg.header.stamp_ns, "nav_reset", msg.reason)
        stamp = msg.header.stamp_ns
        if isinstance(msg, BeaconRange):
            rng, k, late = self._check_range(msg)
            outs = self._advance(stamp)
            if late:
                outs += self._insert_late(k, rng)
            else:
                self._open.setdefault(k, {})[rng.beacon_id] = rng
            return outs
        if isinstance(msg, SpeedLog):
            vals: tuple[float, ...] = (msg.v_forward_mps, msg.v_starboard_mps)
        elif isinstance(msg, Heading):
            vals = (msg.heading_rad,)
        elif isinstance(msg, Depth):
            vals = (msg.depth_m,)
        elif isinstance(msg, Current):
            vals = (msg.u_north_mps, msg.u_east_mps)
        else:
            raise InputRejected("unexpected_type", type(msg).__name__)
        self._check_sample(msg, vals)
        outs = self._advance(stamp)
        if isinstance(msg, SpeedLog):
            self.dr.speed.add(stamp, vals)
        elif isinstance(msg, Heading):
            self.dr.heading.add(stamp, vals)
        elif isinstance(msg, Depth):
            self.depth_m = msg.depth_m
        else:
            self.dr.current.add(stamp, vals)
        return outs

    def flush(self, until_stamp_ns: int | None = None) -> list[Message]:
        """Close every open epoch up to ``until_stamp_ns`` (all epochs with data if None): end of a scenario."""
        if self._next_k is None:
            return []
        if until_stamp_ns is None:
            last = max([*self._open.keys(), self._next_k - 1])
            k_end = last
            if self.dr.speed.stamps:
                k_end = max(k_end, -((self.off_ns - self.dr.speed.stamps[-1]) // self.dt_ns))
            until_stamp_ns = self.t_ns(k_end) + self.lat_ns + 1
        return self._advance(until_stamp_ns)

    # ---- input checks (before any state change) -----------------------------------------------------------------
    def _check_sample(self, msg: SpeedLog | Heading | Depth | Current, vals: tuple[float, ...]) -> None:
        """``vals``: the sample's values (what ``step`` stores)."""
        name = type(msg).__name__
        stamp = msg.header.stamp_ns
        for v in vals:
            if not math.isfinite(v):
                raise InputRejected("non_finite", f"{name} at {stamp} ns")
        limit = _PHYSICAL_LIMITS.get(name)
        if limit is not None and not all(limit[0] <= v <= limit[1] for v in vals):
            raise InputRejected("out_of_range", f"{name} at {stamp} ns: {vals} outside {limit}")
        last = self._last.get(name)
        dr_input = isinstance(msg, SpeedLog | Heading)
        if last is not None and stamp < last:
            raise InputRejected("stamp_backwards", f"{name} stamp {stamp} ns < last {last} ns")
        if last is not None and stamp == last and dr_input:
            raise InputRejected("duplicate", f"{name} stamp {stamp} ns repeated")
        if dr_input and self._next_k is not None and stamp <= self.t_ns(self._next_k - 1):
            raise InputRejected("late", f"{name} at {stamp} ns is older than the last closed epoch")
        self._last[name] = stamp

    def _check_range(self, msg: BeaconRange) -> tuple[_Range, int, bool]:
        cfg = self.cfg
        stamp = msg.header.stamp_ns
        if msg.range_m is not None:
            y = float(msg.range_m)
            T = y / cfg.c_nominal_mps
        elif msg.travel_time_s is not None:
            T = float(msg.travel_time_s)
            y = cfg.c_nominal_mps * T
        else:
            raise InputRejected("missing_range", "neither range_m nor travel_time_s")
        if not (math.isfinite(y) and math.isfinite(T)):
            raise InputRejected("non_finite", f"range to {msg.beacon_id}")
        if y <= 0.0 or T <= 0.0:
            raise InputRejected("non_positive", f"range {y} m to {msg.beacon_id}")
        b = self.beacons.get(msg.beacon_id)
        if b is None:
            raise InputRejected("unknown_beacon", f"beacon_id {msg.beacon_id!r} is not in the beacon table")
        k = (stamp - self.off_ns + self.dt_ns // 2) // self.dt_ns
        if abs(stamp - self.t_ns(k)) > self.tol_ns:
            raise InputRejected("off_epoch", f"stamp {stamp} ns is {abs(stamp - self.t_ns(k)) / 1e6:.1f} ms off grid")
        # physically impossible ranges (5.4): below the vertical separation or beyond reception
        sig = cfg.gate_sigma_k * cfg.sigma_range_m
        dz = abs(b[2] - self.depth_m) if self.depth_m is not None else 0.0
        if y < dz - sig or y > math.hypot(cfg.D_max_m, dz if self.depth_m is not None else b[2] + 20.0) + sig:
            raise InputRejected("impossible_range", f"{y:.1f} m to {msg.beacon_id} (dz {dz:.1f} m)")
        rng = _Range(msg.beacon_id, y, T, stamp)
        late = self._next_k is not None and k < self._next_k
        if late:
            entry = self._unprocessed_entry(k)
            if entry is None or entry.rows:
                raise InputRejected("late", f"range to {msg.beacon_id} for closed epoch {k}")
            self._range_rate_gate(rng, neighbours=True)
            return rng, k, True
        if msg.beacon_id in self._open.get(k, {}):
            raise InputRejected("duplicate", f"second range to {msg.beacon_id} at epoch {k}")
        if self.bank is None:
            self._range_rate_gate(rng, neighbours=False)
        return rng, k, False

    def _range_rate_gate(self, rng: _Range, neighbours: bool) -> None:
        """Pre-launch range-rate gate |y_s - y_s'| <= (V_max + |U|)|t_s - t_s'| + k sqrt(2) sigma ([IMPL] 5.4)."""
        cfg = self.cfg
        vmax = cfg.v_max_mps + self.dr.current_speed()
        sig = cfg.gate_sigma_k * math.sqrt(2.0) * cfg.sigma_range_m

        def ok(other: tuple[int, float]) -> bool:
            return abs(rng.y_m - other[1]) <= vmax * abs(rng.stamp_ns - other[0]) / NS + sig

        if neighbours:
            for other in self._buffer_neighbours(rng):
                if not ok(other):
                    raise InputRejected("range_rate", f"late range to {rng.beacon_id} inconsistent with neighbours")
            return
        last = self._rr_last.get(rng.beacon_id)
        if last is None or rng.stamp_ns <= last[0] or ok(last):
            self._rr_last[rng.beacon_id] = (rng.stamp_ns, rng.y_m)
            return
        rej = self._rr_rej.get(rng.beacon_id)
        if rej is not None and rej[0] > last[0] and ok(rej):
            # two consecutive mutually consistent ranges contradict the anchor: re-anchor on them
            self._rr_last[rng.beacon_id] = (rng.stamp_ns, rng.y_m)
            self._rr_rej.pop(rng.beacon_id, None)
            return
        self._rr_rej[rng.beacon_id] = (rng.stamp_ns, rng.y_m)
        raise InputRejected(
            "range_rate",
            f"range {rng.y_m:.1f} m to {rng.beacon_id} differs from {last[1]:.1f} m "
            f"{(rng.stamp_ns - last[0]) / NS:.1f} s earlier beyond the range-rate bound",
        )

    def _all_buffer(self) -> list[BufferedEpoch]:
        if self.bank is not None:
            return self.bank.buffer[: self.bank.N - self.bank.processed]
        return self.buffer

    def _unprocessed_entry(self, k: int) -> BufferedEpoch | None:
        for e in self._all_buffer():
            if e.k == k:
                return e
        return None

    def _buffer_neighbours(self, rng: _Range) -> list[tuple[int, float]]:
        before = after = None
        for e in self._all_buffer():
            for r in e.rows:
                if r.key == rng.beacon_id:
                    if r.stamp_ns < rng.stamp_ns:
                        before = (r.stamp_ns, r.value)
                    elif after is None:
                        after = (r.stamp_ns, r.value)
        return [o for o in (before, after) if o is not None]

    def _insert_late(self, k: int, rng: _Range) -> list[Message]:
        entry = self._unprocessed_entry(k)
        if entry is None or entry.rows or entry.depth_m is None:
            return [self._event(self.t_ns(k), "rejected", reason="late", detail=f"range to {rng.beacon_id}")]
        entry.rows.append(self._row("s", k, rng, entry.depth_m))
        return []

    # ---- epochs ------------------------------------------------------------------------------------------------
    def _advance(self, stamp: int) -> list[Message]:
        if self._next_k is None:
            self._next_k = -((-(stamp - self.off_ns - self.lat_ns)) // self.dt_ns)
            return []
        outs: list[Message] = []
        n_due = (stamp - self.lat_ns - 1 - self.off_ns) // self.dt_ns - self._next_k + 1
        if n_due > self.cfg.max_epochs_per_step:
            outs += self._reset(stamp, "time_jump", f"{n_due} epochs skipped")
            self._open.clear()
            self._next_k = -((-(stamp - self.off_ns - self.lat_ns)) // self.dt_ns)
            return outs
        while self.t_ns(self._next_k) + self.lat_ns < stamp:
            outs += self._close(self._next_k)
            self._next_k += 1
        return outs

    def _row(self, block: str, k: int, r: _Range, depth: float) -> Row:
        bx, by, bz = self.beacons[r.beacon_id]
        return RangeRow(block, k, r.stamp_ns, r.beacon_id, r.y_m, bx, by, bz, depth, r.T_s)

    def _close(self, k: int) -> list[Message]:
        t_k = self.t_ns(k)
        dr = self.dr.integrate(t_k - self.dt_ns, t_k)
        self.dr.trim(t_k)
        ranges = list(self._open.pop(k, {}).values())
        outs: list[Message] = []
        if ranges and self.depth_m is None:
            for r in ranges:
                outs.append(self._event(t_k, "rejected", reason="no_depth", detail=f"range to {r.beacon_id}"))
            ranges = []
        ranges = [r for r in ranges if r.beacon_id in self.beacons]
        try:
            if self.bank is None:
                outs += self._pre_launch(k, t_k, dr, ranges)
            else:
                outs += self._post_launch(k, t_k, dr, ranges)
        except (np.linalg.LinAlgError, FloatingPointError) as exc:
            # [IMPL] a filter that lost positive definiteness is not trusted further: reported, fresh buffer
            outs += self._reset(t_k, "numerical", f"{type(exc).__name__}: {exc}"[:4000])
            outs.append(self._fix(t_k, "WAITING", dr))
        return outs

    def _pre_launch(self, k: int, t_k: int, dr: DrInterval, ranges: list[_Range]) -> list[Message]:
        cfg = self.cfg
        outs: list[Message] = []
        if not dr.valid and self.buffer:
            # backward prediction cannot cross a DR gap: truncate the buffer at the gap (5.4); one event per gap,
            # the epochs dropped while the gap lasts are counted in buffer_dropped
            n = len(self.buffer)
            self.buffer_dropped += n
            self.buffer = []
            if not self._in_gap:
                outs.append(self._event(t_k, "buffer_truncated", reason="dr_gap", detail=f"{n} epochs", count=n))
        self._in_gap = not dr.valid
        if len(ranges) >= 2:
            assert self.depth_m is not None
            lr = [initiation.LaunchRange(r.beacon_id, *self.beacons[r.beacon_id], r.y_m, r.T_s) for r in ranges]
            res = initiation.launch(lr, self.depth_m, cfg, k, t_k)
            if res.ok:
                rows = [self._row("i", k, r, self.depth_m) for r in ranges]
                return outs + self._launch(k, t_k, dr, res, len(lr), rows)
            outs.append(self._event(t_k, "launch_postponed", reason=res.reason, detail=res.detail))
        if ranges or self.buffer:
            rows = [self._row("s", k, r, self.depth_m) for r in ranges] if ranges and self.depth_m is not None else []
            self.buffer.append(BufferedEpoch(k, t_k, dr, rows, self.depth_m))
            dropped = 0
            while len(self.buffer) > cfg.N_max or (self.buffer and not self.buffer[0].rows):
                self.buffer.pop(0)
                dropped += 1
            if dropped:
                self.buffer_dropped += dropped
                if not self._overflowing:
                    outs.append(
                        self._event(t_k, "buffer_overflow", reason="N_max", detail=f"N_max={cfg.N_max}", count=dropped)
                    )
                self._overflowing = True
            self.state = "BUFFERING" if self.buffer else "WAITING"
        outs.append(self._fix(t_k, self.state, dr))
        return outs

    def _launch(
        self, k: int, t_k: int, dr: DrInterval, res: initiation.LaunchResult, n0: int, rows: list[Row]
    ) -> list[Message]:
        cfg = self.cfg
        hyps = [HypothesisFilter(u + 1, c.X0, c.P0, c.A0, c.lnB0) for u, c in enumerate(res.candidates)]
        buffer = self.buffer if (cfg.use_buffered and dr.valid) else []
        outs: list[Message] = []
        if cfg.use_buffered and not dr.valid and self.buffer:
            # the launch interval itself has no DR: the buffer cannot be linked to the launch epoch
            self.buffer_dropped += len(self.buffer)
            outs.append(
                self._event(t_k, "buffer_truncated", reason="dr_gap", detail=f"{len(self.buffer)} epochs at launch")
            )
        self.bank = HypothesisBank(cfg, self.motion, hyps, buffer, dr, rows)
        self.buffer = []
        self.k0, self.launch_stamp_ns = k, t_k
        self.last_range_used_ns = t_k
        outs += [
            self._event(
                t_k,
                "launch",
                detail=f"n0={n0} N={self.bank.N} hypotheses={len(hyps)}",
                grid_nodes=res.grid_nodes,
                cluster_sizes=res.cluster_sizes,
                centres_m=[[x, y] for x, y in res.centres],
            )
        ]
        report = self.bank.launch_steps()
        if len(hyps) == 1:
            self.source, self.accepted, self.resolved_stamp_ns = "unique", 1, t_k
            status = "UNIQUE"
        else:
            status = "LAUNCH"
        outs += self._decide(t_k)
        if self.source in ("resolved", "merged"):
            status = "RESOLVED" if self.source == "resolved" else "MERGED"
        self.state = "SINGLE" if len(self.bank.hyps) == 1 else "AMBIGUOUS"
        outs.append(self._fix(t_k, status, dr, report, n_current=0))
        return outs

    def _decide(self, t_k: int) -> list[Message]:
        assert self.bank is not None
        d = self.bank.decide()
        if d is None:
            return []
        self.resolved_stamp_ns = t_k
        self._decision_lr = d.log_ratio
        if d.kind == "decision":
            self.source, self.accepted = "resolved", d.hypothesis_id
            detail = ""
            if d.exact is not None:
                ekf = self.bank.log_ratio_at_decision
                detail = f"exact over {d.exact.epochs} epochs"
                if d.exact.log_ratio_robust is not None:
                    detail += f"; robust log10 {d.exact.log_ratio_robust / math.log(10):.3f}"
                if ekf is not None:
                    detail += f"; ekf log10 {ekf / math.log(10):.3f}"
            return [
                self._event(
                    t_k,
                    "decision",
                    reason="exact" if d.exact is not None else "ekf",
                    detail=detail,
                    hypothesis_id=d.hypothesis_id,
                    log10_ratio=d.log_ratio / math.log(10),
                )
            ]
        self.source, self.accepted = "merged", None
        return [self._event(t_k, "merge", log10_ratio=d.log_ratio / math.log(10))]

    def _post_launch(self, k: int, t_k: int, dr: DrInterval, ranges: list[_Range]) -> list[Message]:
        assert self.bank is not None
        rows = [self._row("i", k, r, self.depth_m) for r in ranges] if ranges and self.depth_m is not None else []
        was = len(self.bank.hyps)
        report = self.bank.epoch_step(dr, rows)
        outs: list[Message] = []
        if report.rejected_current or report.rejected_buffered:
            outs.append(
                self._event(
                    t_k,
                    "rejected",
                    reason="innovation_gate",
                    detail=", ".join(report.rejected_keys)[:4000],
                    count=report.rejected_current + report.rejected_buffered,
                )
            )
        if report.used_current:
            self.last_range_used_ns = t_k
            self._consec_rejected = 0
        elif rows:
            self._consec_rejected += 1
            if self._consec_rejected >= self.cfg.divergence_epochs:
                outs.append(
                    self._event(t_k, "divergence", reason="innovation_gate", detail=f"{self._consec_rejected} epochs")
                )
                outs += self._reset(t_k, "divergence", "re-launch from a fresh buffer")
                outs.append(self._fix(t_k, "WAITING", dr))
                return outs
        outs += self._decide(t_k) if was == 2 else []
        if was == 2 and len(self.bank.hyps) == 2:
            status = "AMBIGUOUS"
        elif was == 2:
            status = "RESOLVED" if self.source == "resolved" else "MERGED"
        else:
            age = (t_k - (self.last_range_used_ns or t_k)) / NS
            status = "DR_ONLY" if age >= self.cfg.dr_only_after_s else "TRACKING"
        self.state = "SINGLE" if len(self.bank.hyps) == 1 else "AMBIGUOUS"
        outs.append(self._fix(t_k, status, dr, report, n_current=len(rows)))
        return outs

    def _reset(self, stamp: int, reason: str, detail: str) -> list[Message]:
        self._reset_estimation()
        return [self._event(stamp, "filter_reset", reason=reason, detail=detail)]

    # ---- outputs -----------------------------------------------------------------------------------------------
    def _make(self, cls: type[M], **kw: Any) -> M:
        """Build an output model, validated unless ``validate_outputs`` is False (Monte-Carlo speed)."""
        return self._make_from(cls, kw)

    def _make_from(self, cls: type[M], kw: dict[str, Any]) -> M:
        """:meth:`_make` from a dict of the fields (not unpacked and packed again: the fix has two dozen)."""
        if self._validate:
            return cls(**kw)
        return _construct(cls, kw)

    def _header(self, stamp: int) -> Header:
        return self._make_from(Header, {"stamp_ns": max(stamp, 0), "frame_id": self._frame_id})

    def _event(self, stamp: int, kind: str, **kw: Any) -> LblEvent:
        kw.setdefault("cluster_sizes", [])
        kw.setdefault("centres_m", [])
        return self._make(LblEvent, header=self._header(stamp), platform=self.cfg.platform, kind=kind, **kw)

    def _position(self, mean: list[float], cov: list[list[float]]) -> GaussianEstimate:
        return gaussian(self._frame_id, POSITION, mean, cov, validate=self._validate)

    def _pos_cov(self, P: np.ndarray) -> list[list[float]]:
        return self._pos_cov_list(P[:2, :2].tolist())

    def _pos_cov_list(self, P: list[list[float]]) -> list[list[float]]:
        """3x3 position covariance (x, y from the state covariance, depth variance sigma_depth^2)."""
        return [[P[0][0], P[0][1], 0.0], [P[1][0], P[1][1], 0.0], [0.0, 0.0, self._sd2]]

    def _fix(
        self, t_k: int, status: str, dr: DrInterval, report: StepReport | None = None, n_current: int = 0
    ) -> LblFix:
        cfg = self.cfg
        bank = self.bank
        depth = self.depth_m if self.depth_m is not None else 0.0
        common: dict[str, Any] = {
            "header": self._header(t_k),
            "platform": cfg.platform,
            "status": status,
            "log10_threshold": self._log10_threshold,
            "launch_stamp_ns": self.launch_stamp_ns,
            "resolved_stamp_ns": self.resolved_stamp_ns,
            "buffer_dropped": self.buffer_dropped,
            "degraded": (not dr.valid) or dr.gap_s > 0.0,
        }
        if bank is None:
            common.update(valid=False, buffered_epochs=len(self.buffer), hypotheses=[])
            return self._make_from(LblFix, common)
        probs = bank.probabilities()
        hyps = []
        for h in bank.hyps:
            X, P = h.current()
            hyps.append(
                self._make_from(
                    Hypothesis,
                    {
                        "hypothesis_id": h.hyp_id,
                        "estimate": self._position([float(X[IX]), float(X[IY]), depth], self._pos_cov(P)),
                        "probability": float(probs[h.hyp_id]),
                    },
                )
            )
        lr = bank.log_ratio()
        if lr is None and status in ("RESOLVED", "MERGED"):
            lr = self._decision_lr
        common.update(
            hypotheses=hyps,
            log10_ratio=None if lr is None else lr / math.log(10),
            buffered_epochs=bank.N,
            processed_buffered=bank.processed,
            saved_progress=bank.processed / bank.N if bank.N else 1.0,
            catching_up=bank.catching_up,
            ranges_used=report.used_current if report else 0,
            ranges_rejected=report.rejected_current if report else 0,
        )
        if len(bank.hyps) != 1:
            common["valid"] = False
            return self._make_from(LblFix, common)
        X, P = bank.hyps[0].current()
        x = X.tolist()
        cov = P.tolist()
        common.update(
            valid=True,
            estimate=self._position([x[IX], x[IY], depth], self._pos_cov_list(cov)),
            accepted_hypothesis=self.accepted,
            hypothesis_source=self.source,
            state=gaussian(self._frame_id, LBL_STATE, x, cov, validate=self._validate),
            sigma_dc_mps=math.sqrt(max(cov[IDC][IDC], 0.0)),
            sigma_dK_rad=math.sqrt(max(cov[IDK][IDK], 0.0)),
            sigma_dU_north_mps=math.sqrt(max(cov[IUN][IUN], 0.0)),
            sigma_dU_east_mps=math.sqrt(max(cov[IUE][IUE], 0.0)),
        )
        return self._make_from(LblFix, common)
