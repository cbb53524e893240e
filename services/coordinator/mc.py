"""``fixstream mc`` plugin of the coordinator: the digest's §6.5 protocol checks on a run of an ``rd_group`` scenario.

:func:`run_core` runs :class:`~services.coordinator.protocol.CoordinatorProtocol` (what the service runs) on the
group's uplink (``fixstream/group/<group>/uplink/**``, in order) and calls :func:`run_metrics`, a pure function of
what it published (``BeaconAssignment``, ``DepartureGrant``, ``CoordinatorReply``: from ``run_core`` or from a
recording of ``coordinator/<group>``) and the scenario's events. Per run: the assignments (epochs strictly
increasing, reasons), the grants (vehicle, epoch, time), the beacons at each grant (T-CO-1: at least
``min_beacons`` *others*), whether every assigned member was a docked beacon, the fewest beacons once the
preliminary phase ended, and the replies (refused inputs by reason). :func:`aggregate` sums the runs.

Parameters (``estimators[].params``): ``group`` (default: the scenario's only ``rd_group`` group), ``min_beacons``
(3, the paper's rule), ``config`` (:class:`~services.coordinator.config.CoordinatorConfig` overrides of the
in-process run; the simulator's ``coordinator_config`` should be the same).
"""

from __future__ import annotations

from collections import Counter
from itertools import pairwise
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from schemas.rd_nav import BeaconAssignment, CoordinatorReply, DepartureGrant, VehicleStatus
from services.player.scenario import Scenario
from services.player.simulators import Event
from shared import keys

from .config import CoordinatorConfig
from .protocol import CoordinatorProtocol
from .service import assignment_key, grant_key, group_key, reply_key

OFFLINE_ONLY: tuple[str, ...] = ()


class Params(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    group: str | None = Field(default=None, description="the group; None: the scenario's only rd_group group")
    min_beacons: int = Field(default=3, ge=1, description="beacons that must remain besides a departing one [P]")
    config: dict[str, Any] = Field(default_factory=dict, description="CoordinatorConfig overrides of run_core")

    @model_validator(mode="after")
    def _check(self) -> Params:
        if self.group is not None:
            keys.chunk(self.group)
        try:
            CoordinatorConfig.model_validate(self.config)
        except ValidationError as exc:
            first = exc.errors()[0]
            raise ValueError(f"config.{'.'.join(str(p) for p in first['loc'])}: {first['msg']}") from None
        return self


def _group(p: Params, scenario: Scenario) -> str:
    if p.group is not None:
        return p.group
    groups = [s.params.get("group", "group1") for s in scenario.simulators if s.kind == "rd_group"]
    if len(groups) != 1:
        raise ValueError(f"scenario {scenario.name}: {len(groups)} rd_group simulators; name one in params.group")
    return str(groups[0])


def run_metrics(
    outputs: list[Event], events: list[Event], params: dict[str, Any], scenario: Scenario
) -> dict[str, Any]:
    """Protocol figures of one run from what the coordinator published and the group's status reports."""
    p = Params.model_validate(params, strict=True)
    g = _group(p, scenario)
    prefix = f"{group_key(g, 'uplink')}/"
    # the timeline: status reports (inputs) and the coordinator's decisions, by stamp (inputs first at a tie)
    timeline: list[tuple[int, int, Any]] = []
    for i, ev in enumerate(events):
        if ev.key.startswith(prefix) and isinstance(ev.msg, VehicleStatus):
            timeline.append((ev.stamp_ns, 0, (i, ev.msg)))
    assignments: list[BeaconAssignment] = []
    grants: list[DepartureGrant] = []
    replies = 0
    refused: Counter[str] = Counter()
    for j, ev in enumerate(outputs):
        m = ev.msg
        if isinstance(m, BeaconAssignment) and ev.key == assignment_key(g):
            assignments.append(m)
            timeline.append((m.header.stamp_ns, 1, (j, m)))
        elif isinstance(m, DepartureGrant) and ev.key == grant_key(g, m.auv_id):
            grants.append(m)
            timeline.append((m.header.stamp_ns, 1, (j, m)))
        elif isinstance(m, CoordinatorReply) and ev.key == reply_key(g):
            replies += 1
            if m.rejected is not None:
                refused[m.rejected] += 1
    timeline.sort(key=lambda x: (x[0], x[1], x[2][0]))
    beacons: set[str] = set()
    fewest: int | None = None
    preliminary_over = False
    grant_rows: list[dict[str, Any]] = []
    bad_grants = 0
    non_beacon_members = 0
    for n, (stamp, _, (_, m)) in enumerate(timeline):
        if isinstance(m, VehicleStatus):
            if m.event in ("DOCKED", "AT_BASE"):
                beacons.add(m.auv_id)
            elif m.event in ("DEPARTED", "FAULT"):
                beacons.discard(m.auv_id)
        elif isinstance(m, BeaconAssignment):
            non_beacon_members += sum(1 for k in (m.leader_id, *m.follower_ids) if k not in beacons)
        elif isinstance(m, DepartureGrant):
            others = len(beacons - {m.auv_id})
            bad_grants += int(others < p.min_beacons)
            grant_rows.append({"auv_id": m.auv_id, "epoch": m.epoch, "t_s": stamp * 1e-9, "other_beacons": others})
            beacons.discard(m.auv_id)  # granted: no longer a beacon (it stops transmitting)
        if n + 1 < len(timeline) and timeline[n + 1][0] == stamp:
            continue  # count once everything of this instant is done (the reports at t = 0 come one by one)
        if len(beacons) >= p.min_beacons:
            preliminary_over = True
        if preliminary_over:
            fewest = len(beacons) if fewest is None else min(fewest, len(beacons))
    epochs = [a.epoch for a in assignments]
    return {
        "group": g,
        "assignments": len(assignments),
        "epochs": epochs,
        "epochs_increasing": all(b > a for a, b in pairwise(epochs)),
        "assignment_reasons": dict(Counter(a.reason for a in assignments)),
        "active_sets": [[a.leader_id, *a.follower_ids] for a in assignments],
        "grants": grant_rows,
        "grants_with_too_few_others": bad_grants,
        "assigned_non_beacons": non_beacon_members,
        "fewest_beacons_after_preliminary": fewest,
        "replies": replies,
        "refused": dict(refused),
    }


def run_core(events: list[Event], params: dict[str, Any], scenario: Scenario) -> dict[str, Any]:
    """The group's uplink through the coordinator protocol in order, then :func:`run_metrics`."""
    p = Params.model_validate(params, strict=True)
    g = _group(p, scenario)
    protocol = CoordinatorProtocol(g, CoordinatorConfig.model_validate(p.config))
    prefix = f"{group_key(g, 'uplink')}/"
    outputs: list[Event] = []
    for ev in events:
        if not ev.key.startswith(prefix):
            continue
        answer = protocol.handle(ev.key, ev.msg)
        for d in answer.decisions:
            key = assignment_key(g) if isinstance(d, BeaconAssignment) else grant_key(g, d.auv_id)
            outputs.append(Event(d.header.stamp_ns, key, d))
        outputs.append(Event(answer.reply.header.stamp_ns, reply_key(g), answer.reply))
    return run_metrics(outputs, events, params, scenario)


def aggregate(per_run: list[dict[str, Any]]) -> dict[str, Any]:
    """Totals over the runs (and the worst case of each check)."""
    if not per_run:
        return {"runs": 0}
    fewest = [
        r["fewest_beacons_after_preliminary"] for r in per_run if r["fewest_beacons_after_preliminary"] is not None
    ]
    refused: Counter[str] = Counter()
    for r in per_run:
        refused.update(r["refused"])
    return {
        "runs": len(per_run),
        "group": per_run[0]["group"],
        "assignments": sum(r["assignments"] for r in per_run),
        "grants": sum(len(r["grants"]) for r in per_run),
        "grants_with_too_few_others": sum(r["grants_with_too_few_others"] for r in per_run),
        "assigned_non_beacons": sum(r["assigned_non_beacons"] for r in per_run),
        "epochs_increasing": all(r["epochs_increasing"] for r in per_run),
        "fewest_beacons_after_preliminary": min(fewest) if fewest else None,
        "replies": sum(r["replies"] for r in per_run),
        "refused": dict(refused),
    }


__all__ = ["OFFLINE_ONLY", "Params", "aggregate", "run_core", "run_metrics"]
