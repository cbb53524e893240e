"""Monte-Carlo plugin of ``fixstream mc`` (see :mod:`tools.montecarlo`): the core over the player's events.

For each run, the reference map is rebuilt exactly as the run's ``terrain_nav`` simulator built it (its
parameters from the scenario, the terrain seed from its ``Truth`` extras, ``map_file`` if named), the
vehicle's INS / radio-altimeter / baro / reset messages go through :meth:`TerrainNavigator.step` in event
order, and :func:`services.terrain_nav.metrics.score_run` scores the outputs against the truth stream.

Per run: availability (a valid fix within ``availability_s``) and the time of the first valid fix, the fix
errors in cells, false fixes (> 1 cell on either axis), verdict states and how often each of C2-C4 was
false once C1 held (which condition blocked), vertical-channel errors against truth and against
3 sqrt(P_hh), and the refused inputs by reason. :func:`aggregate` adds them up over runs.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from schemas import Truth
from schemas.terrain_nav import TerrainFix, TerrainVerdict
from services.player.scenario import Scenario
from services.player.simulators import Event
from shared import keys
from shared.errors import InputRejected
from shared.truth import truths_of

from . import metrics
from .config import TerrainNavConfig
from .core import TerrainNavigator
from .service import ESTIMATOR, VERDICT_SUFFIX
from .simulator import KIND, TerrainFlightParams, scenario_world
from .topics import BARO_KIND, INS_KIND, RADALT_KIND, RESET_KIND


class Params(BaseModel):
    """``estimators[].params`` of a scenario for ``kind: terrain_nav``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    vehicle: str | None = Field(
        default=None, description="platform of the terrain_nav simulator (default: the only one)"
    )
    config: dict[str, Any] = Field(default_factory=dict, description="TerrainNavConfig overrides (digest §6 names)")
    availability_s: float = Field(
        default=40.0, gt=0.0, description="a valid fix within this long counts as available, s"
    )

    @model_validator(mode="after")
    def _config_valid(self) -> Params:
        try:
            TerrainNavConfig(**self.config)
        except ValidationError as exc:
            problems = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
            raise ValueError(f"config: {problems}") from None
        return self


def _simulator_params(scenario: Scenario, vehicle: str | None) -> TerrainFlightParams:
    found = []
    for i, spec in enumerate(scenario.simulators):
        p = scenario.simulator_params(i)
        if spec.kind == KIND and isinstance(p, TerrainFlightParams) and vehicle in (None, p.platform):
            found.append(p)
    if len(found) != 1:
        which = f"platform {vehicle!r}" if vehicle else "a vehicle (params.vehicle)"
        raise ValueError(f"scenario {scenario.name}: {len(found)} terrain_nav simulators match {which}")
    return found[0]


def _truths(events: list[Event], vehicle: str, scenario: Scenario) -> list[Truth]:
    truths = truths_of(events, vehicle)
    if not truths:
        raise ValueError(f"scenario {scenario.name}: no Truth of {vehicle} in the events")
    return truths


def run_metrics(
    outputs: list[Event], events: list[Event], params: dict[str, Any], scenario: Scenario
) -> dict[str, Any]:
    """Metrics of one run from what the estimator published (``TerrainVerdict`` and ``TerrainFix`` events, in
    publication order per key) scored against the vehicle's ``Truth`` in ``events``: a pure function of the two,
    so a recording gives the same figures as the in-process run (:func:`run_core`). The ``RESET`` verdict the
    service publishes when the player's end marker starts its next session (detail ``scenario <name> ended``)
    is not part of the run and is not counted."""
    p = Params.model_validate(params)
    sim = _simulator_params(scenario, p.vehicle)
    truths = _truths(events, sim.platform, scenario)
    # the service's own RESET verdict after the player's end marker (its new session) is not part of the run
    session_end = f"scenario {scenario.name} ended"
    published = [
        ev.msg
        for ev in outputs
        if isinstance(ev.msg, TerrainFix)
        or (isinstance(ev.msg, TerrainVerdict) and not (ev.msg.state == "RESET" and ev.msg.detail == session_end))
    ]
    scored = metrics.score_run(published, metrics.TruthTrack(truths, sim.cell_m), p.availability_s)
    return {**scored, "terrain_seed": int(truths[0].extra["terrain_seed"])}


#: keys :func:`run_core` adds to :func:`run_metrics`: the core's own counters, which nothing published carries
OFFLINE_ONLY = ("rejected", "core_counters")


def run_core(events: list[Event], params: dict[str, Any], scenario: Scenario) -> dict[str, Any]:
    """Metrics of one run: the core fed the vehicle's input messages in event order, then :func:`run_metrics`."""
    p = Params.model_validate(params)
    sim = _simulator_params(scenario, p.vehicle)
    vehicle = sim.platform
    terrain_seed = int(_truths(events, vehicle, scenario)[0].extra["terrain_seed"])
    world = scenario_world(sim, terrain_seed)
    nav = TerrainNavigator(world.ref_map, TerrainNavConfig(**p.config), source=f"{KIND}/mc")
    prefixes = tuple(f"{keys.ROOT}/sensor/{vehicle}/{k}/" for k in (INS_KIND, RADALT_KIND, BARO_KIND, RESET_KIND))
    fix_key, verdict_key = keys.fix(ESTIMATOR, vehicle), keys.fix(ESTIMATOR, vehicle, VERDICT_SUFFIX)
    outputs: list[Event] = []
    rejected: Counter[str] = Counter()
    for ev in events:
        if not ev.key.startswith(prefixes):
            continue
        try:
            produced = nav.step(ev.msg)
        except InputRejected as exc:
            rejected[exc.reason] += 1
            continue
        for msg in produced:
            key = fix_key if isinstance(msg, TerrainFix) else verdict_key
            outputs.append(Event(msg.header.stamp_ns, key, msg))
    return {
        **run_metrics(outputs, events, params, scenario),
        "rejected": dict(sorted(rejected.items())),
        "core_counters": dict(sorted(nav.counters.items())),
    }


def aggregate(per_run: list[dict[str, Any]]) -> dict[str, Any]:
    """The core's aggregate metrics, plus the refused inputs by reason over all runs."""
    rejected: Counter[str] = Counter()
    for r in per_run:
        rejected.update(r.get("rejected", {}))
    return {**metrics.aggregate(per_run), "rejected": dict(sorted(rejected.items()))}
