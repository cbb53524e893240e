"""``fixstream mc`` plugin of the LBL estimator: the digest's Monte-Carlo metrics (section 3.1, Fig. 5) of one vehicle.

:func:`run_metrics` is a pure function of what the estimator published (its ``LblFix`` on
``fixstream/fix/lbl/<vehicle>`` and ``LblEvent`` on ``.../event``, exactly what a recording holds) and of the
scenario's events (the vehicle's ``Truth``): the run's trace (:func:`services.lbl_nav.offline.
trace_from_outputs`) scored by :func:`services.lbl_nav.metrics.run_metrics` — resolution time after launch,
decision or merge, wrong decision (the accepted hypothesis is not the one nearest the truth at launch), and per
time of the grid the position error and the filter's sigma of the single-hypothesis fix. Times are relative to
the simulated launch epoch (``start_s + pre_launch_s`` of the scenario's ``lbl_nav`` simulator).

:func:`run_core` runs the estimator offline on the events (one :class:`~services.lbl_nav.core.LblNavCore` fed the
vehicle's sensor events in order and flushed at the end: the service's outputs) and returns
:func:`run_metrics` of its outputs, plus what a recording cannot give (:data:`OFFLINE_ONLY`): ``without``, the
same metrics of a second core that drops the buffered data at launch (``use_buffered = False``, the paper's
"without buffered data", paired on the same run), and ``rejected``, the inputs the core refused.

:func:`aggregate` gives, with and without buffered data (:func:`services.lbl_nav.metrics.aggregate_runs`):
η(t), the share of runs resolved by t (every ``dt`` s), the correct share and the cumulative wrong decisions;
the resolution-time distribution (share resolved, median, 90th percentile, the times); the actual and the
filter-computed RMS of x, y and horizontal over the runs resolved correctly at t; and the paired comparison
(share of runs with t_with ≤ t_without).

Parameters (``estimators[].params`` of the scenario, :class:`Params`): ``vehicle`` (default: the scenario's only
``lbl_nav`` simulator), ``config`` (any :class:`~services.lbl_nav.config.LblNavConfig` field, e.g. S2's
``{N_max: 97, sigma_dK_rad: 0, sigma_dU_mps: 0}``; the service must run with the same values for a recording to
give the same figures), ``without_buffered`` (default true), ``grid_step_s`` (default 5 s) and ``horizon_s``
(default: the simulator's post-launch time within the scenario).
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas.lbl_nav import LblEvent, LblFix
from services.player.scenario import Scenario
from services.player.simulators import Event
from shared import keys
from shared.errors import InputRejected
from shared.mc_params import check_config_overrides
from shared.truth import truths_of

from . import metrics
from .config import LblNavConfig
from .core import LblNavCore
from .offline import trace_from_outputs
from .service import event_key, fix_key
from .simulator import LblSimParams, sim_params

NS = 1_000_000_000
#: keys :func:`run_core` adds to :func:`run_metrics`: what nothing published carries
OFFLINE_ONLY = ("without", "rejected")


class Params(BaseModel):
    """``estimators[].params`` of an ``lbl_nav`` estimator in a scenario."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    vehicle: str | None = Field(default=None, description="vehicle id; None: the scenario's only lbl_nav vehicle")
    config: dict[str, Any] = Field(default_factory=dict, description="LblNavConfig overrides")
    without_buffered: bool = Field(default=True, description="also run use_buffered = False on the same events")
    grid_step_s: float = Field(default=5.0, gt=0.0, le=3600.0, description="RMS time grid step after launch, s")
    horizon_s: float | None = Field(default=None, gt=0.0, le=1e6, description="post-launch horizon, s")

    @model_validator(mode="after")
    def _check(self) -> Params:
        if self.vehicle is not None:
            keys.chunk(self.vehicle)
        check_config_overrides(
            self.config, "platform", "the vehicle as params.vehicle", lambda: self.core_config("check")
        )
        return self

    def core_config(self, vehicle: str, **overrides: Any) -> LblNavConfig:
        """The core's configuration (outputs built without re-validation: the same values, Monte-Carlo speed)."""
        return LblNavConfig.model_validate({**self.config, "platform": vehicle, "validate_outputs": False, **overrides})


def _setup(params: dict[str, Any], scenario: Scenario) -> tuple[Params, str, LblSimParams, float]:
    """(params, vehicle, its simulator parameters, horizon after launch in s)."""
    p = Params.model_validate(params, strict=True)
    sp = sim_params(scenario, p.vehicle)
    vehicle = p.vehicle or sp.platform
    horizon = min(sp.end_s, scenario.duration_s) - sp.launch_s
    if p.horizon_s is not None:
        horizon = min(horizon, p.horizon_s)
    return p, vehicle, sp, max(horizon, 0.0)


def _grid(step_s: float, horizon_s: float) -> list[float]:
    n = math.floor(horizon_s / step_s + 1e-9)
    return [k * step_s for k in range(n + 1)]


def variant_metrics(
    outputs: list[Event], truth: dict[int, tuple[float, float]], vehicle: str, t0_ns: int, grid: list[float]
) -> dict[str, Any]:
    """:func:`metrics.run_metrics` of one estimator's published outputs, plus its event counts and the time
    the buffered data were used up (``catch_up_done_s``, after launch)."""
    fk, ek = fix_key(vehicle), event_key(vehicle)
    outs = [ev.msg for ev in outputs if (ev.key == fk and isinstance(ev.msg, LblFix)) or ev.key == ek]
    trace = trace_from_outputs(outs, truth, t0_ns)
    out = metrics.run_metrics(trace, grid)
    del out["seed"], out["rejected_inputs"]  # the run is the mc run index; rejections are not published
    fixes = [m for m in outs if isinstance(m, LblFix)]
    launched = [f for f in fixes if f.launch_stamp_ns is not None and f.header.stamp_ns >= f.launch_stamp_ns]
    done = next((f for f in launched if not f.catching_up), None)
    out["fixes"] = len(fixes)
    out["launch_t_s"] = None if not launched else (launched[0].header.stamp_ns - t0_ns) / NS
    out["catch_up_done_s"] = (
        None if done is None or done.launch_stamp_ns is None else (done.header.stamp_ns - done.launch_stamp_ns) / NS
    )
    out["buffered_epochs"] = launched[0].buffered_epochs if launched else 0
    out["events"] = dict(sorted(Counter(m.kind for m in outs if isinstance(m, LblEvent)).items()))
    return out


def _truth(events: list[Event], vehicle: str) -> dict[int, tuple[float, float]]:
    return {m.header.stamp_ns: (m.position_m[0], m.position_m[1]) for m in truths_of(events, vehicle)}


def run_metrics(
    outputs: list[Event], events: list[Event], params: dict[str, Any], scenario: Scenario
) -> dict[str, Any]:
    """Metrics of one run from what the vehicle's estimator published and the vehicle's truth in ``events``."""
    p, vehicle, sp, horizon = _setup(params, scenario)
    grid = _grid(p.grid_step_s, horizon)
    t0_ns = round(sp.launch_s * NS)
    return {
        "vehicle": vehicle,
        "horizon_s": horizon,
        "with": variant_metrics(outputs, _truth(events, vehicle), vehicle, t0_ns, grid),
    }


def run_estimator(events: list[Event], cfg: LblNavConfig, vehicle: str) -> tuple[list[Event], int]:
    """One core fed the vehicle's sensor events in order, flushed at the end (what the service publishes at the
    player's end marker); returns the outputs as Events on the service's keys and the number of refused inputs."""
    core = LblNavCore(cfg)
    prefix = f"{keys.ROOT}/sensor/{vehicle}/"
    fk, ek = fix_key(vehicle), event_key(vehicle)
    produced: list[Any] = []
    rejected = 0
    for ev in events:
        if not ev.key.startswith(prefix):
            continue
        try:
            produced += core.step(ev.msg)
        except InputRejected:
            rejected += 1
    produced += core.flush()
    outputs = [Event(m.header.stamp_ns, fk if isinstance(m, LblFix) else ek, m) for m in produced]
    return outputs, rejected


def run_core(events: list[Event], params: dict[str, Any], scenario: Scenario) -> dict[str, Any]:
    """Metrics of one run: the estimator offline on the events, then :func:`run_metrics`; plus the offline-only
    ``without`` (buffered data dropped at launch, same events) and ``rejected``."""
    p, vehicle, sp, horizon = _setup(params, scenario)
    outputs, rejected = run_estimator(events, p.core_config(vehicle), vehicle)
    out = run_metrics(outputs, events, params, scenario)
    if p.without_buffered:
        wo, _ = run_estimator(events, p.core_config(vehicle, use_buffered=False), vehicle)
        t0_ns = round(sp.launch_s * NS)
        out["without"] = variant_metrics(wo, _truth(events, vehicle), vehicle, t0_ns, _grid(p.grid_step_s, horizon))
    out["rejected"] = rejected
    return out


def _aggregate_variant(runs: list[dict[str, Any]], horizon_s: float) -> dict[str, Any]:
    agg = metrics.aggregate_runs(runs, horizon_s)
    del agg["rejected_inputs"]  # not published: run_core's "rejected" counts them
    fine = _grid(1.0, horizon_s)
    agg["eta"] = metrics.eta_curve(runs, fine)  # resolution times only: every second
    done = [r["catch_up_done_s"] for r in runs if r["catch_up_done_s"] is not None]
    agg["catch_up_done_s"] = {"min": min(done), "max": max(done)} if done else None
    events: Counter[str] = Counter()
    for r in runs:
        events.update(r["events"])
    agg["events"] = dict(sorted(events.items()))
    return agg


def aggregate(per_run: list[dict[str, Any]]) -> dict[str, Any]:
    """Over all runs, with and without buffered data: η(t), wrong decisions, the resolution-time distribution,
    actual and computed RMS over the correctly resolved runs (:func:`metrics.aggregate_runs`), and the paired
    comparison of the resolution times."""
    if not per_run:
        return {"runs": 0}
    horizon = min(float(r["horizon_s"]) for r in per_run)
    out: dict[str, Any] = {"runs": len(per_run), "vehicle": per_run[0]["vehicle"], "horizon_s": horizon}
    out["with"] = _aggregate_variant([r["with"] for r in per_run], horizon)
    if all("without" in r for r in per_run):
        out["without"] = _aggregate_variant([r["without"] for r in per_run], horizon)
        tw = np.array([_time(r["with"]) for r in per_run])
        to = np.array([_time(r["without"]) for r in per_run])
        out["paired"] = {
            "with_not_later_share": float(np.mean(tw <= to)),
            "both_resolved": int(np.sum(np.isfinite(tw) & np.isfinite(to))),
            "with_earlier": int(np.sum(tw < to)),
            "with_later": int(np.sum(tw > to)),
        }
    if all("rejected" in r for r in per_run):
        out["rejected"] = sum(int(r["rejected"]) for r in per_run)
    return out


def _time(r: dict[str, Any]) -> float:
    t = r["resolution_t_s"]
    return math.inf if t is None else float(t)


__all__ = ["OFFLINE_ONLY", "Params", "aggregate", "run_core", "run_estimator", "run_metrics", "variant_metrics"]
