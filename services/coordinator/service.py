"""The coordinator service: the base station's control centre of one AUV group (digest 002 §2.4, §4.8, §7.3 S7).

A thin adapter around :class:`~services.coordinator.protocol.CoordinatorProtocol` (the core plus its reply).
Keys (``<group>`` = ``FIXSTREAM_COORDINATOR_GROUP``, default the instance name):

* in, one subscription ``fixstream/group/<group>/uplink/**`` (one subscription, so one publisher's messages are
  handled in the order they were sent): ``VehicleStatus`` on ``.../uplink/<vehicle>/status`` (acoustic
  telemetry of the vehicles), ``AcousticArrival`` on ``.../uplink/base/acoustic`` (navigation packets heard at
  the base: beacons alive, new epoch confirmed) and ``BeaconTable`` on ``.../uplink/base/nodes`` (the surveyed
  node table; also settable as ``FIXSTREAM_COORDINATOR_NODE_TABLE_NED_M``);
* out: ``BeaconAssignment`` on ``fixstream/group/<group>/assignment`` (a new epoch whenever the active set
  changes), ``DepartureGrant`` on ``fixstream/group/<group>/grant/<vehicle>``, and one ``CoordinatorReply`` per
  input on ``fixstream/group/<group>/reply`` (``reply: false`` turns them off): the closed-loop simulation waits
  for it to know the base station's decisions on what it sent (``docs/rd_nav.md``, the closed loop);
* ``fixstream/diag/coordinator/<instance>``: refused inputs (the codec's reasons such as ``non_finite``, and
  ``unexpected_type``, ``unknown_node``, ``unknown_sender``, ``not_docked``) and the core's alarms as events
  (``beacon_timeout``, ``below_min_beacons``, ``no_active_set``, ``departed_without_grant``);
  ``fixstream/status/coordinator/<instance>``, ``fixstream/alive/coordinator/<instance>`` (service base).

Time is the data clock of the inputs; the service never reads the wall clock for a decision. At the end of a
scenario (every message the player's end marker announced has arrived) the core starts afresh
(``reset_on_scenario_end``). Deterministic: the outputs depend only on the order of the inputs and equal
:class:`CoordinatorProtocol` in-process on the same messages.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Any, ClassVar, Literal, cast

from pydantic import Field
from pydantic_settings import SettingsConfigDict

from schemas import Message
from schemas.rd_nav import BeaconAssignment, DepartureGrant
from shared import keys
from shared.service import Output, Service, Subscription
from shared.settings import ServiceSettings, ZenohSettings

from .config import CoordinatorConfig
from .protocol import CoordinatorProtocol

log = logging.getLogger("fixstream.coordinator")

#: alarm -> diag level
ALARM_LEVELS: dict[str, Literal["info", "warning", "error"]] = {
    "beacon_timeout": "warning",
    "below_min_beacons": "warning",
    "no_active_set": "warning",
    "departed_without_grant": "error",
}


def group_key(group: str, *sub: str) -> str:
    """``fixstream/group/<group>[/<sub>...]``."""
    return "/".join([keys.ROOT, "group", keys.chunk(group), *(keys.chunk(s) for s in sub)])


def uplink_key(group: str, sender: str, kind: str) -> str:
    """``fixstream/group/<group>/uplink/<sender>/<kind>`` (sender = a vehicle id, or ``base``)."""
    return group_key(group, "uplink", sender, kind)


def uplink_expr(group: str) -> str:
    """The coordinator's one subscription: ``fixstream/group/<group>/uplink/**``."""
    return f"{group_key(group, 'uplink')}/**"


def assignment_key(group: str) -> str:
    return group_key(group, "assignment")


def grant_key(group: str, auv_id: str) -> str:
    return group_key(group, "grant", auv_id)


def reply_key(group: str) -> str:
    return group_key(group, "reply")


class CoordinatorSettings(ServiceSettings, CoordinatorConfig):
    """``FIXSTREAM_COORDINATOR_*``: every :class:`CoordinatorConfig` parameter (digest defaults), one variable each
    (``FIXSTREAM_COORDINATOR_MIN_BEACONS=3``, ``FIXSTREAM_COORDINATOR_TAU_SLOTS_S=[0.5, 3.5]``), plus the instance
    name and the service's own options below."""

    model_config = SettingsConfigDict(env_prefix="FIXSTREAM_COORDINATOR_", extra="ignore", frozen=True)

    group: keys.Chunk | None = Field(default=None, description="vehicle group (key chunk); None: the instance name")
    reply: bool = Field(default=True, description="publish a CoordinatorReply for every input (closed-loop runs)")
    report_alarms: bool = Field(default=True, description="report the core's alarms on diag")

    def core_config(self) -> CoordinatorConfig:
        """The core's configuration: the CoordinatorConfig fields of these settings."""
        return CoordinatorConfig(**{name: getattr(self, name) for name in CoordinatorConfig.model_fields})


class CoordinatorService(Service):
    """Base-station coordinator of one group; see the module docstring."""

    name: ClassVar[str] = "coordinator"

    def __init__(self, settings: CoordinatorSettings, zenoh_settings: ZenohSettings | None = None) -> None:
        super().__init__(settings, zenoh_settings)
        self.config = settings
        self.group = settings.group or self.instance
        self.protocol = CoordinatorProtocol(self.group, settings.core_config())
        self.in_expr = uplink_expr(self.group)
        self.alarms: Counter[str] = Counter()
        self.decisions: Counter[str] = Counter()

    # ----- Service hooks ---------------------------------------------------------------------------------------
    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.in_expr, self.on_input)]

    def on_input(self, key: str, msg: Message) -> list[Output]:
        """One validated uplink message (the base decoded it once): run the protocol, publish decisions + reply.

        A refused input still gets its reply (published first), then the refusal is raised for the base to count
        and report."""
        answer = self.protocol.handle(key, msg)
        out: list[Output] = []
        for d in answer.decisions:
            if isinstance(d, BeaconAssignment):
                out.append(Output(assignment_key(self.group), d))
                self.decisions["assignment"] += 1
            elif isinstance(d, DepartureGrant):
                out.append(Output(grant_key(self.group, d.auv_id), d))
                self.decisions["grant"] += 1
        if self.config.reply:
            out.append(Output(reply_key(self.group), answer.reply))
        core = self.protocol.core
        for alarm, n in answer.alarms.items():
            detail = f"{core.alarms[alarm]} so far; beacons {sorted(core.beacons())}"
            level = ALARM_LEVELS.get(alarm, "warning")
            stamp = msg.header.stamp_ns
            self.count_event(
                self.alarms, key, alarm, detail, n=n, level=level, stamp_ns=stamp, report=self.config.report_alarms
            )
        if answer.rejected is not None:
            for o in out:  # the reply (and nothing else: a refused input decides nothing)
                self.publish(o.key, o.msg)
            raise answer.rejected
        return out

    def new_run(self, reason: str) -> list[Output]:
        """A fresh core for the next run."""
        self.protocol.reset()
        return list(super().new_run(reason))

    def status_extra(self) -> dict[str, Any]:
        core = self.protocol.core
        a = core.assignment
        return {
            "group": self.group,
            "keys": {
                "in": self.in_expr,
                "assignment": assignment_key(self.group),
                "grant": f"{group_key(self.group, 'grant')}/*",
                "reply": reply_key(self.group),
            },
            "config_digest": self.protocol.digest,
            "epoch": a.epoch if a is not None else 0,
            "active_set": [a.leader_id, *a.follower_ids] if a is not None else [],
            "beacons": sorted(core.beacons()),
            "vehicles": {k: r.state for k, r in sorted(core.vehicles.items())},
            "done_queue": [auv for _, auv in core.done_queue],
            "decisions": dict(self.decisions),
            "alarms": dict(self.alarms),
            "sessions": self.sessions,
        }


def build() -> CoordinatorService:
    """The service configured from ``FIXSTREAM_COORDINATOR_*`` and ``FIXSTREAM_ZENOH_*``."""
    settings = cast(CoordinatorSettings, CoordinatorSettings.load())
    return CoordinatorService(settings)


__all__ = [
    "CoordinatorService",
    "CoordinatorSettings",
    "assignment_key",
    "build",
    "grant_key",
    "group_key",
    "reply_key",
    "uplink_expr",
    "uplink_key",
]
