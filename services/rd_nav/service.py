"""The rd_nav service: RD-LBL + DR navigation of ONE moving AUV (digest 002), a thin adapter around :class:`RdNavCore`.

decode -> validate -> :meth:`RdNavCore.step` -> encode. Everything estimation-related (cycle assembly, packet
checks, clock jumps, gating, re-initialisation, status words) is the core's (digest §4.4, §7.3, §7.4); the adapter
adds the transport, the key names and the reporting. Keys (``<auv>`` = ``FIXSTREAM_RD_NAV_AUV_ID``, default the
instance name):

* in, ONE subscription ``fixstream/sensor/<auv>/**`` dispatching by message type, so everything the vehicle's
  navigation computer receives is handled in the order it was sent (two subscriptions could reorder it): DR
  sensors (``SpeedLog``, ``Attitude`` or ``Heading``, ``Depth``, ``SoundSpeed``), modem arrivals
  (``AcousticArrival``), the vehicle's own mission events (``VehicleStatus``: ``DEPARTED`` starts the filter in a
  disc around the dock, ``DOCKED`` stops it), the node table (``BeaconTable``), the active beacon set as received
  from the base (``BeaconAssignment``) and ``NavReset``. The player plugin ``rd_group`` publishes them on
  ``.../dvl/dvl0``, ``.../attitude/ahrs0``, ``.../depth/press0``, ``.../sound_speed/svs0``, ``.../acoustic/modem0``,
  ``.../nav/status``, ``.../nav/nodes`` and ``.../nav/assignment``;
* out: ``RdNavFix`` of the particle filter on ``fixstream/fix/rd/<auv>`` (``kind`` CYCLE at each cycle's leader
  arrival, PROPAGATED carried by DR to the latest sensor time), the EKF shadow's on ``fixstream/fix/rd/<auv>/ekf``
  and every assembled ``TdoaCycle`` on ``fixstream/fix/rd/<auv>/cycle`` (``publish_ekf``, ``publish_cycles``);
* ``fixstream/diag/rd_nav/<instance>``: every refused input with its reason — the codec's (``non_finite`` for a
  NaN or infinite value, ``out_of_bounds``, ``bad_msgpack``, ``missing_field``, ...), ``unexpected_type`` and the
  core's (``stamp_backwards``, ``unknown_node``, ``unknown_sender``, ``beacon_pos_mismatch``, ``bad_packet``,
  ``duplicate``, ``stale_packet``, ``no_leader``, ``unassigned_follower``, ``wrong_receiver``,
  ``implausible_sound_speed``, ``no_start_position``) — and the filter's events: ``cycle_<reason>`` (a cycle
  not used: ``cycle_clock_jump``, ``cycle_nis_gate``, ``cycle_no_overlap``, ``cycle_mixed_epoch``, ...),
  ``reinit``, ``outlier_dropped`` and ``status_<word>`` (the PF status changed, e.g. ``status_dr_only``);
  ``fixstream/status/rd_nav/<instance>`` and ``fixstream/alive/rd_nav/<instance>`` (service base).

**End of a scenario**: once every message the player's end marker announced on this vehicle's keys has arrived
(the ``Service`` base waits for them) the service starts a fresh core (``reset_on_scenario_end``), so the next
run starts from nothing. Deterministic: the outputs depend only on the order of the inputs (time comes from the
stamps; the particle filter's generator from ``seed``) and equal :class:`RdNavCore` in-process on the same
messages.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Any, ClassVar, Literal, cast

from pydantic import Field
from pydantic_settings import SettingsConfigDict

from schemas import (
    AcousticArrival,
    Attitude,
    BeaconTable,
    Depth,
    Heading,
    Message,
    NavReset,
    SoundSpeed,
    SpeedLog,
)
from schemas.rd_nav import BeaconAssignment, RdNavFix, TdoaCycle, VehicleStatus
from shared import keys
from shared.service import Output, Service, Subscription
from shared.settings import ServiceSettings, ZenohSettings, core_config_of

from .config import RdNavConfig
from .core import RdNavCore

log = logging.getLogger("fixstream.rd_nav")

#: the estimator chunk of the output keys (``fixstream/fix/rd/<auv>``)
ESTIMATOR = "rd"
INPUTS: tuple[type[Message], ...] = (
    SpeedLog,
    Attitude,
    Heading,
    Depth,
    SoundSpeed,
    AcousticArrival,
    VehicleStatus,
    BeaconTable,
    BeaconAssignment,
    NavReset,
)
#: cycle rejections reported as warnings (the others are info: a normal part of navigating)
_WARN_CYCLES = {"CLOCK_JUMP", "MIXED_EPOCH", "NON_FINITE_INNOVATION", "WEIGHT_FAILURE", "DR_UNAVAILABLE"}


def input_expr(auv_id: str) -> str:
    """``fixstream/sensor/<auv>/**``: the service's one subscription."""
    return f"{keys.ROOT}/sensor/{keys.chunk(auv_id)}/**"


def fix_key(auv_id: str) -> str:
    """``fixstream/fix/rd/<auv>``: the particle filter's fixes (CYCLE and PROPAGATED)."""
    return keys.fix(ESTIMATOR, auv_id)


def ekf_key(auv_id: str) -> str:
    return keys.fix(ESTIMATOR, auv_id, "ekf")


def cycle_key(auv_id: str) -> str:
    return keys.fix(ESTIMATOR, auv_id, "cycle")


def output_key(auv_id: str, msg: Message) -> str:
    """Where the service publishes one of the core's outputs."""
    if isinstance(msg, TdoaCycle):
        return cycle_key(auv_id)
    if isinstance(msg, RdNavFix) and msg.estimator == "EKF":
        return ekf_key(auv_id)
    return fix_key(auv_id)


class RdNavSettings(ServiceSettings, RdNavConfig):
    """``FIXSTREAM_RD_NAV_*``: every :class:`RdNavConfig` parameter (digest defaults), one variable each
    (``FIXSTREAM_RD_NAV_N_PARTICLES=1000``, ``FIXSTREAM_RD_NAV_FLEET_IDS=[auv1, auv2]``), plus the instance name and
    the service's own options below. ``auv_id`` defaults to the instance name."""

    model_config = SettingsConfigDict(env_prefix="FIXSTREAM_RD_NAV_", extra="ignore", frozen=True)

    auv_id: keys.Chunk | None = Field(  # type: ignore[assignment]
        default=None, description="the moving AUV this instance navigates (key chunk); None: the instance name"
    )
    publish_ekf: bool = Field(default=True, description="publish the EKF shadow's fixes on .../ekf")
    publish_cycles: bool = Field(default=True, description="publish every TdoaCycle on .../cycle")
    report_events: bool = Field(default=True, description="report the filter's events on diag")

    def core_config(self, auv_id: str) -> RdNavConfig:
        """The core's configuration: the RdNavConfig fields of these settings, for ``auv_id``."""
        return core_config_of(self, RdNavConfig, auv_id=auv_id)


class RdNavService(Service):
    """Navigation of one moving AUV of the group; see the module docstring."""

    name: ClassVar[str] = "rd_nav"

    def __init__(self, settings: RdNavSettings, zenoh_settings: ZenohSettings | None = None) -> None:
        super().__init__(settings, zenoh_settings)
        self.config = settings
        self.auv_id = settings.auv_id or self.instance
        self.core_config = settings.core_config(self.auv_id)
        self.core = RdNavCore(self.core_config)
        self.in_expr = input_expr(self.auv_id)
        self.events: Counter[str] = Counter()
        self.outputs: Counter[str] = Counter()
        self._status: str | None = None

    # ----- Service hooks ---------------------------------------------------------------------------------------
    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.in_expr, self.on_input, accepts=INPUTS)]

    def on_input(self, key: str, msg: Message) -> list[Output]:
        """One validated sample of the vehicle (the base decoded it once and refused other types): run the core."""
        produced = self.core.step(msg)  # InputRejected propagates: the base counts and reports it
        out: list[Output] = []
        for m in produced:
            if isinstance(m, RdNavFix) and m.estimator == "PF" and m.kind == "CYCLE":
                self._cycle_events(key, m)
            if isinstance(m, TdoaCycle) and not self.config.publish_cycles:
                continue
            if isinstance(m, RdNavFix) and m.estimator == "EKF" and not self.config.publish_ekf:
                continue
            self.outputs[type(m).__name__ if not isinstance(m, RdNavFix) else f"{m.estimator}/{m.kind}"] += 1
            out.append(Output(output_key(self.auv_id, m), m))
        return out

    def new_run(self, reason: str) -> list[Output]:
        """A fresh core for the next run (the vehicle's stamps start again from 0)."""
        self.core = RdNavCore(self.core_config)
        self._status = None
        return list(super().new_run(reason))

    def status_extra(self) -> dict[str, Any]:
        core = self.core
        est = core.estimate()
        return {
            "auv_id": self.auv_id,
            "keys": {"in": self.in_expr, "fix": fix_key(self.auv_id), "ekf": ekf_key(self.auv_id)}
            | {"cycle": cycle_key(self.auv_id)},
            "nav_status": core.status,
            "initialised": core.initialised,
            "docked": core.docked,
            "position_ned_m": None if est is None else [float(est[0][0]), float(est[0][1])],
            "reinit_count": core.reinit_count,
            "core": dict(sorted(core.counts.items())),
            "events": dict(self.events),
            "outputs": dict(self.outputs),
            "sessions": self.sessions,
        }

    # ----- internals -------------------------------------------------------------------------------------------
    def _cycle_events(self, key: str, fix: RdNavFix) -> None:
        """Report what a PF cycle fix says happened: a rejected cycle, a re-initialisation, a dropped late
        arrival, a change of the status word."""
        if fix.cycle_status == "REJECTED" and fix.reject_reason is not None:
            level: Literal["info", "warning"] = "warning" if fix.reject_reason in _WARN_CYCLES else "info"
            self._event(key, f"cycle_{fix.reject_reason.lower()}", f"{fix.leader_id}#{fix.cycle_seq}", level, fix)
        if "REINIT" in fix.flags:
            self._event(key, "reinit", f"re-seeded from snapshot fixes ({fix.reinit_count} so far)", "warning", fix)
        for flag in fix.flags:
            if flag.startswith("OUTLIER:"):
                self._event(key, "outlier_dropped", f"late arrival of {flag[8:]} left out", "info", fix)
        if fix.status != self._status:
            if self._status is not None:
                self._event(key, f"status_{fix.status.lower()}", f"{self._status} -> {fix.status}", "info", fix)
            self._status = fix.status

    def _event(self, key: str, reason: str, detail: str, level: Literal["info", "warning"], msg: RdNavFix) -> None:
        stamp = msg.header.stamp_ns
        self.count_event(
            self.events, key, reason, detail, level=level, stamp_ns=stamp, report=self.config.report_events
        )


def build() -> RdNavService:
    """The service configured from ``FIXSTREAM_RD_NAV_*`` and ``FIXSTREAM_ZENOH_*``."""
    settings = cast(RdNavSettings, RdNavSettings.load())
    return RdNavService(settings)


__all__ = [
    "ESTIMATOR",
    "INPUTS",
    "RdNavService",
    "RdNavSettings",
    "build",
    "cycle_key",
    "ekf_key",
    "fix_key",
    "input_expr",
    "output_key",
]
