"""``fixstream mc`` plugin of rd_nav: the digest's §5.4/§6 error statistics of one moving AUV of an ``rd_group`` run.

:func:`run_core` runs :class:`~services.rd_nav.core.RdNavCore` (what the service runs) on the vehicle's events
(everything on ``fixstream/sensor/<auv>/**``, in order), files its outputs on the service's keys and calls
:func:`run_metrics`: a pure function of those outputs (or of what a recording holds from ``rd_nav/<auv>``) and the
scenario's events. Scored: the particle filter's CYCLE fixes (``fixstream/fix/rd/<auv>``) at their leader-arrival
epoch against ``fixstream/truth/<auv>`` at the same stamp (the ``rd_group`` simulator publishes a Truth there;
otherwise linear interpolation), skipping the first ``skip_first_cycles`` fixes after each departure (the digest
scores 1437 of 1440 cycles). Figures per run (:mod:`services.rd_nav.metrics`): per-axis (north x, east y) mean
and SD, |e| RMS / p99 / p99.9 / max, consistency RMS|e| / RMS sqrt(tr Q), the EKF shadow's RMS and mean NEES,
re-initialisations, and cycles not used by reason (``TdoaCycle.reject_reason`` of cycles before the filter
started, ``RdNavFix.reject_reason`` after; re-initialising cycles not counted, as the core counts them).
:func:`aggregate` pools the runs (percentiles over all samples).

Parameters (``estimators[].params``, :class:`Params`): ``vehicle`` (default: the group's only moving AUV),
``config`` (any :class:`~services.rd_nav.config.RdNavConfig` field, e.g. ``motion_compensation: false`` for
T-ROB-1's negative control; ``auv_id`` is the vehicle), ``skip_first_cycles``.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas import Message, Truth
from schemas.rd_nav import BeaconAssignment, RdNavFix, TdoaCycle, VehicleStatus
from services.player.scenario import Scenario
from services.player.simulators import Event
from shared import keys
from shared.errors import InputRejected
from shared.mc_params import check_config_overrides
from shared.truth import linear_at, truths_of

from . import consistency
from .config import RdNavConfig
from .core import RdNavCore
from .metrics import aggregate as aggregate_runs
from .metrics import run_metrics as metrics_of_run
from .service import cycle_key, ekf_key, fix_key, output_key

#: keys :func:`run_core` adds to :func:`run_metrics` (nothing published carries them)
OFFLINE_ONLY = ("rejected_inputs", "core_counts")


class Params(BaseModel):
    """``estimators[].params`` of an ``rd_nav`` estimator in a scenario."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    vehicle: str | None = Field(default=None, description="the AUV scored; None: the group's only moving AUV")
    config: dict[str, Any] = Field(default_factory=dict, description="RdNavConfig overrides")
    skip_first_cycles: int = Field(default=3, ge=0, description="cycle fixes not scored after each departure")
    regime_window_s: float = Field(
        default=30.0, gt=0.0, description="a fix is in a manoeuvre if the truth turns or changes speed this close, s"
    )

    @model_validator(mode="after")
    def _check(self) -> Params:
        if self.vehicle is not None:
            keys.chunk(self.vehicle)
        check_config_overrides(self.config, "auv_id", "the AUV as params.vehicle", lambda: self.core_config("check"))
        return self

    def core_config(self, auv_id: str) -> RdNavConfig:
        return RdNavConfig.model_validate({**self.config, "auv_id": auv_id})


def _vehicle(p: Params, events: list[Event]) -> str:
    """The scored AUV: params.vehicle, else the only one that reports DEPARTED in the run."""
    if p.vehicle is not None:
        return p.vehicle
    movers = sorted({e.msg.auv_id for e in events if isinstance(e.msg, VehicleStatus) and e.msg.event == "DEPARTED"})
    if len(movers) != 1:
        raise ValueError(f"{len(movers)} moving AUVs ({', '.join(movers)}): name one in params.vehicle")
    return movers[0]


class _TruthTrack:
    """A vehicle's truth in base NED (north, east): exact at a Truth's stamp, else linearly interpolated."""

    def __init__(self, truths: list[Truth]) -> None:
        self.exact: dict[int, tuple[float, float]] = {}
        for m in truths:
            p = m.position_m
            ne = (p[0], p[1]) if m.header.frame_id == "base_ned" else (p[1], p[0])  # else [east, north, up]
            self.exact[m.header.stamp_ns] = ne
        self.t = np.array(sorted(self.exact), dtype=np.float64)
        self.ne = np.array([self.exact[int(s)] for s in self.t], dtype=np.float64).reshape(-1, 2)

    def at(self, stamp_ns: int) -> tuple[float, float] | None:
        hit = self.exact.get(stamp_ns)
        if hit is not None:
            return hit
        n, e = linear_at(self.t, self.ne, [stamp_ns])[0]
        return None if np.isnan(n) else (float(n), float(e))


def _rows(fixes: list[RdNavFix], truth: _TruthTrack) -> list[tuple[float, ...]]:
    """metrics.COLUMNS rows (t, x, y, qxx, qxy, qyy, true x, true y) of the fixes that have a truth."""
    rows: list[tuple[float, ...]] = []
    for f in fixes:
        tr = truth.at(f.header.stamp_ns)
        if tr is None:
            continue
        (x, y), q = f.estimate.mean, f.estimate.covariance
        rows.append((f.header.stamp_ns * 1e-9, x, y, q[0][0], q[0][1], q[1][1], *tr))
    return rows


def run_metrics(
    outputs: list[Event], events: list[Event], params: dict[str, Any], scenario: Scenario
) -> dict[str, Any]:
    """Metrics of one run from what the vehicle's rd_nav published (``outputs``: its fixes, EKF fixes and cycles;
    anything else is ignored) and the scenario's ``events`` (truth, the vehicle's own status reports)."""
    p = Params.model_validate(params, strict=True)
    auv = _vehicle(p, events)
    truth = _TruthTrack(truths_of(events, auv))
    departures = sorted(
        e.stamp_ns
        for e in events
        if isinstance(e.msg, VehicleStatus)
        and e.msg.auv_id == auv
        and e.msg.event == "DEPARTED"
        and e.key.startswith(f"{keys.ROOT}/sensor/")
    )
    pf: list[RdNavFix] = []
    ekf: list[RdNavFix] = []
    cycles: list[TdoaCycle] = []
    for ev in outputs:
        m = ev.msg
        if isinstance(m, RdNavFix) and m.kind == "CYCLE" and m.auv_id == auv:
            (pf if m.estimator == "PF" else ekf).append(m)
        elif isinstance(m, TdoaCycle) and m.auv_id == auv:
            cycles.append(m)
    scored_pf = _skip(pf, departures, p.skip_first_cycles)
    scored_ekf = _skip(ekf, departures, p.skip_first_cycles)
    rejected: Counter[str] = Counter()
    with_fix = {(f.leader_id, f.cycle_seq, f.header.stamp_ns) for f in pf}
    for c in cycles:  # cycles the filter never saw (before it started)
        if c.status == "REJECTED" and (c.leader_id, c.cycle_seq, c.header.stamp_ns) not in with_fix:
            rejected[c.reject_reason or "UNKNOWN"] += 1
    for f in pf:
        if f.cycle_status == "REJECTED" and "REINIT" not in f.flags:
            rejected[f.reject_reason or "UNKNOWN"] += 1
    status: Counter[str] = Counter(f.status for f in pf)
    cycle_status: Counter[str] = Counter(f.cycle_status for f in pf)
    extra = {
        "vehicle": auv,
        "cycles": len(cycles),
        "pf_cycle_fixes": len(pf),
        "scored": len(scored_pf),
        "status": dict(status),
        "cycle_status": dict(cycle_status),
        "params": p.model_dump(mode="json"),
    }
    reinit = max((f.reinit_count for f in pf), default=0)
    pf_rows, ekf_rows = _rows(scored_pf, truth), _rows(scored_ekf, truth)
    reg = consistency.Regimes(truths_of(events, auv), p.regime_window_s)
    period = _cycle_period(events, auv)
    extra["consistency"] = {
        name: consistency.per_run(rows, reg.of([round(r[0] * 1e9) for r in rows]), period)
        for name, rows in (("pf", pf_rows), ("ekf", ekf_rows))
        if rows
    }
    out = metrics_of_run(pf_rows, ekf_rows, reinit, rejected, {}, extra)
    del out["rejected_inputs"]  # OFFLINE_ONLY: added by run_core
    return out


def _cycle_period(events: list[Event], auv: str) -> float:
    """T_c of the vehicle's first assignment (10 s without one): the epoch grid of the ANEES."""
    for ev in events:
        if isinstance(ev.msg, BeaconAssignment) and ev.key.startswith(f"{keys.ROOT}/sensor/{auv}/"):
            return float(ev.msg.cycle_period_s)
    return 10.0


def _skip(fixes: list[RdNavFix], departures: list[int], k: int) -> list[RdNavFix]:
    """The fixes without the first ``k`` after each departure (and before the first one)."""
    if k == 0:
        return list(fixes)
    out = []
    since: dict[int, int] = Counter()
    for f in fixes:
        leg = sum(1 for d in departures if d <= f.header.stamp_ns)
        since[leg] += 1
        if since[leg] > k:
            out.append(f)
    return out


def run_core(events: list[Event], params: dict[str, Any], scenario: Scenario) -> dict[str, Any]:
    """Metrics of one run: the vehicle's core fed its events in order (as the service is), then :func:`run_metrics`."""
    p = Params.model_validate(params, strict=True)
    auv = _vehicle(p, events)
    core = RdNavCore(p.core_config(auv))
    prefix = f"{keys.ROOT}/sensor/{auv}/"
    outputs: list[Event] = []
    rejected: Counter[str] = Counter()
    for ev in events:
        if not ev.key.startswith(prefix):
            continue
        try:
            produced: list[Message] = core.step(ev.msg)
        except InputRejected as exc:
            rejected[exc.reason] += 1
            continue
        outputs += [Event(m.header.stamp_ns, output_key(auv, m), m) for m in produced]
    return {
        **run_metrics(outputs, events, params, scenario),
        "rejected_inputs": dict(rejected),
        "core_counts": dict(sorted(core.counts.items())),
    }


def aggregate(per_run: list[dict[str, Any]]) -> dict[str, Any]:
    """Over all runs: pooled PF and EKF figures (metrics.aggregate), re-initialisations, rejections by reason."""
    if not per_run:
        return {"runs": 0}
    agg = aggregate_runs([{**r, "rejected_inputs": r.get("rejected_inputs", {})} for r in per_run])
    core_counts: Counter[str] = Counter()
    for r in per_run:
        core_counts.update(r.get("core_counts", {}))
    agg.update(
        vehicle=per_run[0]["vehicle"],
        params=per_run[0]["params"],
        scored=sum(int(r["scored"]) for r in per_run),
        cycles=sum(int(r["cycles"]) for r in per_run),
        core_counts=dict(sorted(core_counts.items())),
        max_run_max_m=max((r["pf_summary"].get("max_m", float("nan")) for r in per_run if r["pf"]["n"]), default=None),
        nis_gated=sum(int(r["rejected_cycles"].get("NIS_GATE", 0)) for r in per_run),
        consistency={
            name: consistency.aggregate([r["consistency"][name] for r in per_run if name in r.get("consistency", {})])
            for name in ("pf", "ekf")
        },
    )
    return agg


__all__ = ["OFFLINE_ONLY", "Params", "aggregate", "cycle_key", "ekf_key", "fix_key", "run_core", "run_metrics"]
