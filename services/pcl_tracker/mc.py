"""Monte-Carlo plugin of the PCL tracker for ``fixstream mc`` (see ``tools/montecarlo.py``).

Each run feeds the events of the tracker's receiver–illuminator pair (``fixstream/sensor/<rx>/pcl/<tx>``,
exactly what the player publishes, in order) to :class:`~services.pcl_tracker.core.PclTracker`, flushes it
at the end, and scores the scan reports against the truth (``fixstream/truth/<target>``) with
:mod:`services.pcl_tracker.metrics`:

* position and velocity errors of the confirmed track matched to each target, per scan (RMSE over time in
  the aggregate);
* OSPA distance per scan between confirmed tracks and live targets (cut-off ``ospa_c_m``, order ``ospa_p``);
* identity (CLEAR MOT track-to-truth association over time): ID switches, split into swaps between targets
  and restarts, fragmentations, breaks, distinct ids per target; GOSPA per scan with its decomposition
  (localisation, missed targets, false tracks); NEES of the matched tracks and NIS of their plots per scan;
* false confirmed tracks: confirmed ids never within ``match_distance_m`` of a target while confirmed.

``params`` are the tracker's parameters (the same names as the service's ``FIXSTREAM_PCL_TRACKER_*``
variables, e.g. ``confirm_M: 3``) plus the metric options of
:class:`~services.pcl_tracker.settings.PclTrackerParamsBase`.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from typing import Any

import numpy as np

from schemas import Truth
from schemas.pcl_tracker import PclScanReport
from schemas.radar import BistaticConfigUpdate, BistaticScan
from services.player.scenario import Scenario
from services.player.simulators import NS_PER_S, Event
from shared.errors import InputRejected
from shared.truth import linear_at

from . import metrics
from .core import PclTracker
from .service import input_key, output_key
from .settings import PclTrackerParams, to_config

#: validates ``estimators[].params`` (strict): the tracker parameters and the metric options
Params = PclTrackerParams


def scenario_targets(scenario: Scenario, receiver_id: str, illuminator_id: str) -> list[str]:
    """Target ids of the scenario's ``pcl_tracker`` simulators of this pair (file order)."""
    from .simulator import PclSimParams

    out: list[str] = []
    for i, spec in enumerate(scenario.simulators):
        if spec.kind != "pcl_tracker":
            continue
        p = scenario.simulator_params(i)
        assert isinstance(p, PclSimParams)
        if p.receiver_id == receiver_id and p.illuminator_id == illuminator_id:
            out += [t for t in p.target_ids() if t not in out]
    return out


def run_metrics(
    outputs: list[Event], events: list[Event], params: dict[str, Any], scenario: Scenario
) -> dict[str, Any]:
    """Metrics of one run from what the tracker published (its ``PclScanReport`` events, in order) against the
    targets' ``Truth`` in ``events``: a pure function of the two, so a recording gives the figures of
    :func:`run_core`."""
    p = PclTrackerParams.model_validate(params)
    cfg = to_config(p)
    rx, tx = cfg.geometry.receiver_id, cfg.geometry.illuminator_id
    reports = [
        ev.msg
        for ev in outputs
        if isinstance(ev.msg, PclScanReport) and ev.msg.receiver_id == rx and ev.msg.illuminator_id == tx
    ]
    truth: dict[str, list[tuple[int, list[float]]]] = defaultdict(list)
    for ev in events:
        msg = ev.msg
        if isinstance(msg, Truth):
            vel = msg.velocity_mps if msg.velocity_mps is not None else [float("nan")] * 3
            truth[msg.platform].append((msg.header.stamp_ns, [*msg.position_m, *vel]))
    scans = [r for r in reports if r.trigger == "scan"]
    targets = p.targets if p.targets is not None else scenario_targets(scenario, rx, tx)
    stamps = np.array([r.header.stamp_ns for r in scans], dtype=np.int64)
    true_states = np.full((len(scans), len(targets), 6), np.nan)
    for j, name in enumerate(targets):
        if truth.get(name):
            series = truth[name]  # exact samples, linear in between, NaN outside the sampled span
            true_states[:, j] = linear_at([t for t, _ in series], [x for _, x in series], stamps)
    m = metrics.run_metrics(
        reports,
        true_states,
        [r.scan_id for r in scans],
        ospa_c_m=p.ospa_c_m,
        ospa_p=p.ospa_p,
        match_distance_m=p.match_distance_m,
    )
    ids = {t.track_id for r in reports for t in r.tracks}
    return {
        **m,
        "t_s": (stamps / NS_PER_S).tolist(),
        "scan_ids": [r.scan_id for r in scans],
        "targets": list(targets),
        "n_scans": len(scans),
        "n_tracks_created": len(ids),
    }


#: keys :func:`run_core` adds to :func:`run_metrics`: the core's own counters, which nothing published carries
OFFLINE_ONLY = ("refused_inputs", "core_metrics")


def run_core(events: list[Event], params: dict[str, Any], scenario: Scenario) -> dict[str, Any]:
    """One run: the tracker over the pair's events (flushed at the end), then :func:`run_metrics`."""
    p = PclTrackerParams.model_validate(params)
    cfg = to_config(p)
    rx, tx = cfg.geometry.receiver_id, cfg.geometry.illuminator_id
    key = input_key(rx, tx)
    out_key = output_key(rx, tx)
    core = PclTracker(cfg)
    reports = []
    refused: Counter[str] = Counter()
    for ev in events:
        msg = ev.msg
        if ev.key == key and isinstance(msg, BistaticScan | BistaticConfigUpdate):
            try:
                reports += core.step(msg)
            except InputRejected as exc:
                refused[exc.reason] += 1
    reports += core.flush()
    outputs = [Event(r.header.stamp_ns, out_key, r) for r in reports]
    return {
        **run_metrics(outputs, events, params, scenario),
        "refused_inputs": dict(refused),
        "core_metrics": dict(sorted(core.metrics.items())),
    }


def aggregate(per_run: list[dict[str, Any]]) -> dict[str, Any]:
    """RMSE over time, OSPA per scan, continuity and false tracks over all runs (metrics.aggregate)."""
    if not per_run:
        return {"n_runs": 0}
    agg = metrics.aggregate(per_run)
    t_s = per_run[0]["t_s"]
    same_times = all(r["t_s"] == t_s for r in per_run)
    pos = [v for v in agg["pos_rmse_m"] if v == v]
    vel = [v for v in agg["vel_rmse_mps"] if v == v]
    return {
        **agg,
        "t_s": t_s if same_times else None,
        "pos_rmse_m_last": pos[-1] if pos else None,
        "vel_rmse_mps_last": vel[-1] if vel else None,
        "tracks_created_per_run": float(np.mean([r["n_tracks_created"] for r in per_run])),
        "id_switches_total": int(sum(r["id_switches"] for r in per_run)),
        "id_swaps_total": int(sum(r["id_swaps"] for r in per_run)),
        "id_restarts_total": int(sum(r["id_restarts"] for r in per_run)),
        "fragmentations_total": int(sum(r["fragmentations"] for r in per_run)),
        "breaks_total": int(sum(r["breaks"] for r in per_run)),
        "false_confirmed_tracks_total": int(sum(r["false_confirmed_tracks"] for r in per_run)),
        "refused_inputs": dict(sum((Counter(r["refused_inputs"]) for r in per_run), Counter())),
    }
