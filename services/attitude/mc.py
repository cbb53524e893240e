"""``fixstream mc`` plugin of the attitude estimator: the digest's §3.3/§4 metrics of one radar site's targets.

:func:`run_core` feeds the events of one run (exactly what the player publishes) to one
:class:`~services.attitude.core.AttitudeCore` of the site, then scores every target's estimates against its
truth (``fixstream/truth/<target>``, converted from the scenario frame to the radar frame E) with the core's
metrics module (:class:`~services.attitude.metrics.RunRecorder`): per scan, the wrapped error of each angle
(earth, LOS and aspect), the reported sigma, the raw-baseline error (§2.6) and the position/velocity errors.
:func:`aggregate` combines the runs per target with :func:`services.attitude.metrics.aggregate`: per-scan RMS
and mean errors for filtered and raw estimates, the first scan with RMS under 5 deg and 3 deg, the consistency
of the reported sigmas (sqrt of the mean reported variance / RMS, scans 21-100), plus a ``summary`` at the
digest's table scans.

Parameters (``estimators[].params`` of the scenario, :class:`Params`):

* ``site_id``: the radar site (default: the site of the scenario's only ``attitude`` simulator);
* ``reference`` (default true): the digest's reference-run rules (:func:`~.offline.evaluation_config`:
  angles at every scan from scan 3 on, the service's suppression of undefined angles off), so the figures
  compare with the digest's tables; false scores the service's own configuration;
* ``config``: any :class:`~services.attitude.config.AttitudeConfig` field (e.g. ``sigma_jerk_mps3``); the raw
  baseline is always attached;
* ``thresholds_deg``, ``summary_scans``, ``consistency_scans``, ``phase_first_scan``: what :func:`aggregate`
  reports; ``phases`` (per target and pooled over the targets): the flight-phase statistics of
  :func:`~services.attitude.metrics.phase_table` (turns, other manoeuvres, straight legs, steady straight legs:
  RMS per angle, NEES against its chi-square band, VALID consistency), from the truth's commanded phase;
* ``stream`` (default ``realtime``): ``smoothed`` scores the fixed-lag smoothed estimates instead (flag
  ``SMOOTHED``; needs ``config.smoother_lag_scans`` > 0).
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas import RadarPlot, Truth
from schemas.attitude import AttitudeEstimate
from services.player.scenario import Scenario
from services.player.simulators import Event
from shared import keys
from shared.errors import InputRejected
from shared.mc_params import check_config_overrides

from .config import AttitudeConfig
from .core import AttitudeCore
from .metrics import ANGLE_FIELDS, RunRecorder, phase_samples, phase_table
from .metrics import aggregate as aggregate_records
from .offline import evaluation_config
from .service import ESTIMATOR
from .simulator import AttitudeSimParams, enu_to_nue

#: fields of the digest's reference-run configuration (``evaluation_config``) that differ from the service's
_REFERENCE = evaluation_config()
REFERENCE_RULES: dict[str, Any] = {
    name: getattr(_REFERENCE, name)
    for name in ("v_min_mps", "heading_sigma_factor", "min_normal_force_g", "validate_covariances")
}
#: angles of the summary table
SUMMARY_ANGLES = ("psi_los", "theta_los", "gamma_los", "psi", "theta", "gamma")


class Params(BaseModel):
    """``estimators[].params`` of an ``attitude`` estimator in a scenario."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    site_id: str | None = Field(default=None, description="radar site; None: the scenario's only attitude site")
    reference: bool = Field(default=True, description="the digest's reference-run rules (angles from scan 3)")
    config: dict[str, Any] = Field(default_factory=dict, description="AttitudeConfig overrides")
    thresholds_deg: list[float] = Field(default_factory=lambda: [5.0, 3.0], min_length=1, max_length=10)
    summary_scans: list[int] = Field(default_factory=lambda: [3, 11, 21, 41, 61, 100], max_length=1000)
    consistency_scans: list[int] = Field(default_factory=lambda: [21, 100], min_length=2, max_length=2)
    phase_first_scan: int = Field(default=20, ge=1, description="flight-phase statistics from this scan on")
    stream: Literal["realtime", "smoothed"] = Field(
        default="realtime",
        description="the estimates scored: the real-time ones, or the fixed-lag smoothed ones (needs config"
        " smoother_lag_scans > 0); recorded in the metrics only when not the default",
    )

    @model_validator(mode="after")
    def _check(self) -> Params:
        if self.site_id is not None:
            keys.chunk(self.site_id)
        check_config_overrides(self.config, "site_id", "the site as params.site_id", lambda: self.core_config("check"))
        if self.stream == "smoothed" and not self.core_config("check").smoother_lag_scans:
            raise ValueError("stream 'smoothed' needs config.smoother_lag_scans > 0 (no smoothed estimate otherwise)")
        if any(s < 1 for s in self.summary_scans) or not 1 <= self.consistency_scans[0] <= self.consistency_scans[1]:
            raise ValueError("scan numbers start at 1; consistency_scans is [first, last]")
        return self

    def core_config(self, site_id: str) -> AttitudeConfig:
        fields: dict[str, Any] = dict(REFERENCE_RULES) if self.reference else {}
        fields.update(self.config)
        fields.update(site_id=site_id, raw_output=True)
        return AttitudeConfig.model_validate(fields)


def _site(params: Params, scenario: Scenario) -> tuple[str, list[float]]:
    """(site id, radar position [east, north, up] in the scenario frame) of the estimator's site."""
    sites: dict[str, list[float]] = {}
    for i, spec in enumerate(scenario.simulators):
        if spec.kind == "attitude":
            sp = scenario.simulator_params(i)
            assert isinstance(sp, AttitudeSimParams)
            sites[sp.site_id] = list(sp.site_position_m)
    if params.site_id is not None:
        return params.site_id, sites.get(params.site_id, [0.0, 0.0, 0.0])
    if len(sites) != 1:
        raise ValueError(f"scenario {scenario.name}: {len(sites)} attitude sites; name one in params.site_id")
    site_id, pos = next(iter(sites.items()))
    return site_id, pos


def radar_frame_truth(truth: Truth, site_enu_m: list[float]) -> Truth:
    """A Truth of the scenario frame [east, north, up] moved to the radar frame E [north, up, east] of the site."""
    pos = enu_to_nue(np.asarray(truth.position_m) - np.asarray(site_enu_m)).tolist()
    vel = None if truth.velocity_mps is None else enu_to_nue(np.asarray(truth.velocity_mps)).tolist()
    acc = None if truth.acceleration_mps2 is None else enu_to_nue(np.asarray(truth.acceleration_mps2)).tolist()
    return truth.model_copy(update={"position_m": pos, "velocity_mps": vel, "acceleration_mps2": acc})


def is_realtime(est: AttitudeEstimate) -> bool:
    """An estimate of the real-time stream, not the fixed-lag smoothed one (flag SMOOTHED, stamped L plots back,
    published on its own sub-key): what the metrics and the report score unless asked for the smoothed stream."""
    return "SMOOTHED" not in est.flags


def run_metrics(
    outputs: list[Event], events: list[Event], params: dict[str, Any], scenario: Scenario, smoothed: bool = False
) -> dict[str, Any]:
    """Metrics of one run from what the site published (its ``AttitudeEstimate`` events; COASTING ones are not
    scored) against the targets' truth in ``events``: every target with a plot on the site's radar keys, scored at
    each of its truth samples. A pure function of the two, so a recording gives the figures of :func:`run_core`.
    ``smoothed`` (or ``params.stream: smoothed``): score the fixed-lag smoothed estimates (flag SMOOTHED,
    ``smoother_lag_scans``) instead of the real-time ones."""
    p = Params.model_validate(params, strict=True)
    smoothed = smoothed or p.stream == "smoothed"
    site_id, site_pos = _site(p, scenario)
    config = p.core_config(site_id)
    prefix = f"{keys.ROOT}/sensor/{site_id}/radar/"
    estimates: dict[str, dict[int, AttitudeEstimate]] = {}
    truths: dict[str, list[Truth]] = {}
    truth_keys: dict[str, str] = {}
    for ev in events:
        msg = ev.msg
        if isinstance(msg, RadarPlot) and ev.key.startswith(prefix):
            estimates.setdefault(msg.target_id, {})
        elif isinstance(msg, Truth):
            key = truth_keys.get(msg.platform)
            if key is None:
                key = truth_keys[msg.platform] = keys.truth(msg.platform)
            if ev.key == key:
                truths.setdefault(msg.platform, []).append(msg)
    for ev in outputs:
        est = ev.msg
        if (
            isinstance(est, AttitudeEstimate)
            and est.site_id == site_id
            and est.status != "COASTING"
            and is_realtime(est) != smoothed
        ):
            estimates.setdefault(est.target_id, {})[est.header.stamp_ns] = est
    targets: dict[str, Any] = {}
    for tid, by_stamp in estimates.items():
        recorder = RunRecorder()
        for tr in truths.get(tid, []):
            recorder.add(by_stamp.get(tr.header.stamp_ns), radar_frame_truth(tr, site_pos))
        targets[tid] = recorder.rec
    return {
        "site_id": site_id,
        # a field added later is recorded only when set, so that the metrics of every earlier scenario stay as they were
        "params": p.model_dump(mode="json", exclude={"stream"} if p.stream == "realtime" else None),
        "config": config.model_dump(mode="json"),
        "targets": targets,
    }


#: keys :func:`run_core` adds to :func:`run_metrics`: the core's own counters, which nothing published carries
OFFLINE_ONLY = ("rejected", "core")


def run_core(events: list[Event], params: dict[str, Any], scenario: Scenario) -> dict[str, Any]:
    """Metrics of one run: one core of the site fed the site's radar events in order, then :func:`run_metrics`."""
    outputs, rejected, core = core_outputs(events, params, scenario)
    return {**run_metrics(outputs, events, params, scenario), "rejected": rejected, "core": core}


def core_outputs(
    events: list[Event], params: dict[str, Any], scenario: Scenario
) -> tuple[list[Event], int, dict[str, int]]:
    """(the site's outputs as events, the number of refused inputs, the core's counters) of one core of the site
    fed the site's radar events in order."""
    p = Params.model_validate(params, strict=True)
    site_id, _ = _site(p, scenario)
    core = AttitudeCore(p.core_config(site_id))
    prefix = f"{keys.ROOT}/sensor/{site_id}/radar/"
    out_prefix = f"{keys.ROOT}/fix/{ESTIMATOR}/{site_id}/"  # service.output_key, without its key-chunk check
    outputs: list[Event] = []
    rejected = 0
    for ev in events:
        if not ev.key.startswith(prefix):
            continue
        try:
            produced = core.step(ev.msg)  # type: ignore[arg-type]
        except InputRejected:
            rejected += 1
            continue
        outputs += [Event(est.header.stamp_ns, out_prefix + est.target_id, est) for est in produced]
    return outputs, rejected, dict(sorted(core.counters.items()))


def _at(values: list[Any], scan: int) -> float | None:
    if scan > len(values):
        return None
    v = values[scan - 1]
    return None if v is None or not math.isfinite(v) else float(v)


def aggregate(per_run: list[dict[str, Any]]) -> dict[str, Any]:
    """Per target over all runs: metrics.aggregate (per-scan RMS/mean filtered and raw, first scan below the
    thresholds, sigma consistency) plus a ``summary`` at the ``summary_scans``; the core's counters summed."""
    if not per_run:
        return {"runs": 0, "targets": {}}
    p = Params.model_validate(per_run[0]["params"])
    core_counts: dict[str, int] = {}
    for r in per_run:
        for k, n in r["core"].items():
            core_counts[k] = core_counts.get(k, 0) + int(n)
    target_ids = list(dict.fromkeys(tid for r in per_run for tid in r["targets"]))
    out_targets: dict[str, Any] = {}
    phase_parts: list[dict[str, Any]] = []
    for tid in target_ids:
        records = [r["targets"][tid] for r in per_run if tid in r["targets"]]
        n_scans = min(len(rec["stamp_ns"]) for rec in records)
        if n_scans == 0:
            out_targets[tid] = {"n_runs": len(records), "n_scans": 0}
            continue
        records = [_trim(rec, n_scans) for rec in records]
        k0, k1 = p.consistency_scans
        k1 = min(k1, n_scans)
        k0 = min(k0, k1)
        agg = aggregate_records(records, thresholds_deg=p.thresholds_deg, consistency_scans=(k0, k1))
        summary: dict[str, Any] = {}
        for name in SUMMARY_ANGLES:
            summary[name] = {
                str(scan): {
                    "rms": _at(agg["rms"][name], scan),
                    "mean": _at(agg["mean"][name], scan),
                    "raw_rms": _at(agg["raw_rms"][name], scan),
                    "sigma_rms": _at(agg["sigma_rms"][name], scan),
                }
                for scan in p.summary_scans
                if scan <= n_scans
            }
            summary[name]["consistency_mean_ratio"] = agg["consistency"][name]["mean_ratio"]
        agg["summary"] = summary
        agg["first_stamp_ns"] = records[0]["stamp_ns"][0]
        samples = phase_samples(records, first_scan=p.phase_first_scan)
        agg["phases"] = phase_table([samples])
        phase_parts.append(samples)
        out_targets[tid] = agg
    return {
        "runs": len(per_run),
        "site_id": per_run[0]["site_id"],
        "config": per_run[0]["config"],
        "angles": list(ANGLE_FIELDS),
        "rejected": sum(int(r["rejected"]) for r in per_run),
        "core": dict(sorted(core_counts.items())),
        "phases": phase_table(phase_parts),
        "phase_samples": phase_parts,
        "targets": out_targets,
    }


def _trim(rec: dict[str, Any], n: int) -> dict[str, Any]:
    """A per-run record cut to its first ``n`` scans (runs of one target normally have equal lengths)."""
    out: dict[str, Any] = {}
    for k, v in rec.items():
        if isinstance(v, dict):
            out[k] = {name: vals[:n] for name, vals in v.items()}
        elif isinstance(v, list):
            out[k] = v[:n]
        else:
            out[k] = v
    return out


__all__ = [
    "OFFLINE_ONLY",
    "REFERENCE_RULES",
    "Params",
    "aggregate",
    "core_outputs",
    "radar_frame_truth",
    "run_core",
    "run_metrics",
]
