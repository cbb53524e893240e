"""The LBL navigation service: one instance per vehicle, a thin adapter around :class:`LblNavCore` (digest 000).

decode -> dispatch by type -> :meth:`LblNavCore.step` -> encode. Everything estimation-related (epoch grid,
reorder window, buffering, launch, hypotheses, gating, DR gaps, bad-input rules of the digest's §5.4) is the
core's; the adapter adds the transport, the key names and the reporting. Keys (``<vehicle>`` =
``FIXSTREAM_LBL_NAV_VEHICLE``, default the instance name ``FIXSTREAM_LBL_NAV_INSTANCE``):

* in, ONE subscription ``fixstream/sensor/<vehicle>/**`` (Zenoh delivers each subscription on its own thread,
  so one subscription keeps the publication order of the vehicle's streams): :class:`~schemas.BeaconRange`,
  :class:`~schemas.SpeedLog`, :class:`~schemas.Heading`, :class:`~schemas.Depth`, :class:`~schemas.Current`,
  :class:`~schemas.BeaconTable` (replaces the configured table) and :class:`~schemas.NavReset`, whatever the key
  below the prefix (the ``lbl_nav`` player plugin uses ``lbl/rx0``, ``lbl/beacons``, ``speed_log/log0``,
  ``heading/compass0``, ``depth/depth0``, ``current/model0``). Other message types of the vehicle are ignored
  (counted in the base's ``counters.ignored``);
* out: ``fixstream/fix/lbl/<vehicle>`` (:class:`~schemas.lbl_nav.LblFix`, one per closed epoch) and
  ``fixstream/fix/lbl/<vehicle>/event`` (:class:`~schemas.lbl_nav.LblEvent`: launch, decision, merge, ...);
* ``fixstream/diag/lbl_nav/<instance>``: every refused input with its reason, and the events below;
  ``fixstream/status/lbl_nav/<instance>``, ``fixstream/alive/lbl_nav/<instance>`` (service base).

**Refused** (counted in ``rejected_by_reason``; the core's state is untouched): the codec's reasons
(``non_finite`` for a NaN or infinite field, ``out_of_bounds`` for a negative or zero range, ``bad_msgpack``,
``missing_field``, ...) and the core's ``unknown_beacon``, ``stamp_backwards``, ``late``, ``duplicate``,
``off_epoch``, ``out_of_range`` (a log speed, depth or current beyond physical limits), ``impossible_range`` (a range
below the vertical separation or beyond reception, e.g. a 10 km
outlier), ``range_rate`` (pre-launch range-rate gate), ``non_finite``, ``non_positive``, ``missing_range``,
``bad_beacon_table``.

**Events** (reported on diag, not refused: the input was taken): the core's ``LblEvent`` of kind ``rejected``
under its reason (``innovation_gate``: a range that is an outlier under every live hypothesis, dropped for all;
``late``; ``no_depth``), ``launch_postponed``, ``buffer_overflow``, ``buffer_truncated``, ``divergence`` and
``filter_reset``; and the adapter's ``dr_gap`` (the first epoch without log or heading data: held values,
``degraded`` fixes) and ``dr_restored``. Launch, decision and merge events go to the event key only (counted in
``events``).

**End of a scenario.** Once every message the player's end marker announced on the vehicle's keys has arrived
(the ``Service`` base waits for them), the core closes its open epochs (``flush``) and, with
``reset_on_scenario_end``, a fresh core starts, so a following scenario whose stamps start again from 0 is
accepted. Stopping (SIGTERM) also flushes.

Deterministic: the outputs depend only on the order of the inputs (time comes from the stamps) and equal what
:class:`LblNavCore` gives in-process on the same messages, followed by ``flush()`` at the end marker.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Any, ClassVar, Literal, cast

from pydantic import Field
from pydantic_settings import SettingsConfigDict

from schemas import BeaconRange, BeaconTable, Current, Depth, Heading, Message, NavReset, ScenarioMarker, SpeedLog
from schemas.lbl_nav import LblEvent, LblFix
from shared import keys
from shared.service import Output, Service, Subscription
from shared.settings import ServiceSettings, ZenohSettings, core_config_of

from .config import LblNavConfig
from .core import LblNavCore

log = logging.getLogger("fixstream.lbl_nav")

#: the estimator chunk of the output keys: ``fixstream/fix/lbl/<vehicle>``
ESTIMATOR = "lbl"
EVENT_SUFFIX = "event"
INPUTS: tuple[type[Message], ...] = (BeaconRange, SpeedLog, Heading, Depth, Current, BeaconTable, NavReset)
#: LblEvent kinds reported on diag (with their level); "rejected" is reported under the event's own reason
_DIAG_EVENTS: dict[str, Literal["info", "warning"]] = {
    "rejected": "warning",
    "launch_postponed": "warning",
    "buffer_overflow": "info",
    "buffer_truncated": "warning",
    "divergence": "warning",
    "filter_reset": "warning",
}


def fix_key(vehicle: str) -> str:
    """``fixstream/fix/lbl/<vehicle>``."""
    return keys.fix(ESTIMATOR, vehicle)


def event_key(vehicle: str) -> str:
    """``fixstream/fix/lbl/<vehicle>/event``."""
    return keys.fix(ESTIMATOR, vehicle, EVENT_SUFFIX)


def input_key(vehicle: str) -> str:
    """``fixstream/sensor/<vehicle>/**``: every stream of the vehicle, one subscription."""
    return f"{keys.ROOT}/sensor/{keys.chunk(vehicle)}/**"


class LblNavSettings(ServiceSettings, LblNavConfig):
    """``FIXSTREAM_LBL_NAV_*``: every :class:`LblNavConfig` parameter (digest §5.5 defaults), one variable each
    (``FIXSTREAM_LBL_NAV_DN=10``, ``FIXSTREAM_LBL_NAV_SIGMA_DK_RAD=0.0873``, ``FIXSTREAM_LBL_NAV_BEACONS=[{"beacon_id":
    "B1", "x_east_m": 0, "y_north_m": 0, "depth_m": 100}, ...]``), plus the instance, the vehicle and the service's
    own options below. ``platform`` is the vehicle (default the instance name); ``validate_outputs`` defaults to
    False here (see its description)."""

    model_config = SettingsConfigDict(env_prefix="FIXSTREAM_LBL_NAV_", extra="ignore", frozen=True)

    vehicle: keys.Chunk | None = Field(default=None, description="vehicle id in the keys (default: the instance name)")
    platform: str | None = Field(  # type: ignore[assignment]
        default=None, description="not used: the outputs' platform is the vehicle"
    )
    validate_outputs: bool = Field(
        default=False,
        description="re-validate every output with pydantic (symmetric-PSD covariance checks) before publishing; off "
        "in the service (a fifth of its CPU): the core symmetrises every covariance, the values are the same, and "
        "every consumer validates each message on decode",
    )
    report_events: bool = Field(default=True, description="report the core's problem events on diag")

    def core_config(self, vehicle: str) -> LblNavConfig:
        """The core's configuration: the LblNavConfig fields of these settings, for ``vehicle``."""
        return core_config_of(self, LblNavConfig, platform=vehicle)


class LblNavService(Service):
    """LBL navigation of one vehicle with no prior position (digest 000); see the module docstring."""

    name: ClassVar[str] = "lbl_nav"

    def __init__(self, settings: LblNavSettings, zenoh_settings: ZenohSettings | None = None) -> None:
        super().__init__(settings, zenoh_settings)
        self.config = settings
        self.vehicle = settings.vehicle or self.instance
        self.core_config = settings.core_config(self.vehicle)
        self.core = LblNavCore(self.core_config)
        self.in_key = input_key(self.vehicle)
        self.fix_key = fix_key(self.vehicle)
        self.event_key = event_key(self.vehicle)
        self.events: Counter[str] = Counter()
        self.outputs: Counter[str] = Counter()
        self._degraded = False
        self._gap_start_ns = 0
        self.last_fix: dict[str, Any] | None = None

    # ----- Service hooks ---------------------------------------------------------------------------------------
    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.in_key, self.on_input, accepts=INPUTS, others="ignore")]

    def on_input(self, key: str, msg: Message) -> list[Output]:
        """One validated input of the vehicle (the base decoded it once; other types are counted as ignored): run the
        core (an ``InputRejected`` propagates: the base counts and reports it)."""
        return [self._output(key, m) for m in self.core.step(msg)]

    def flush_run(self, marker: ScenarioMarker) -> list[Output]:
        """The open epochs of the run, closed."""
        return [self._output(keys.scenario(marker.scenario), m) for m in self.core.flush()]

    def new_run(self, reason: str) -> list[Output]:
        """A fresh core for the next run."""
        self.core = LblNavCore(self.core_config)
        self._degraded = False
        return list(super().new_run(reason))

    def on_stop(self) -> None:
        """Stopping: the open epochs are closed and published before the session closes."""
        for out in self.core.flush():
            o = self._output(self.in_key, out)
            self.publish(o.key, o.msg)

    def status_extra(self) -> dict[str, Any]:
        bank = self.core.bank
        return {
            "vehicle": self.vehicle,
            "keys": {"in": self.in_key, "fix": self.fix_key, "event": self.event_key},
            "beacons": sorted(self.core.beacons),
            "state": self.core.state,
            "hypotheses": 0 if bank is None else len(bank.hyps),
            "catching_up": bool(bank is not None and bank.catching_up),
            "buffered_epochs": len(self.core.buffer) if bank is None else bank.N,
            "events": dict(self.events),
            "outputs": dict(self.outputs),
            "sessions": self.sessions,
            "last_fix": self.last_fix,
        }

    # ----- internals -------------------------------------------------------------------------------------------
    def _output(self, key: str, m: Message) -> Output:
        if isinstance(m, LblFix):
            self.outputs["fixes"] += 1
            self.last_fix = {"stamp_ns": m.header.stamp_ns, "status": m.status, "valid": m.valid}
            if m.degraded != self._degraded:
                self._dr_gap(key, m)
            return Output(self.fix_key, m)
        ev = cast(LblEvent, m)
        self.outputs["events"] += 1
        name = (ev.reason or ev.kind) if ev.kind == "rejected" else ev.kind
        level = _DIAG_EVENTS.get(ev.kind)  # None: counted, not reported (launch, decision, merge)
        detail = ev.detail if ev.kind == "rejected" or not ev.reason else f"{ev.reason}: {ev.detail}"
        report = level is not None and self.config.report_events
        self.count_event(
            self.events,
            key,
            name,
            detail,
            n=ev.count,
            level=level or "info",
            stamp_ns=ev.header.stamp_ns,
            report=report,
        )
        return Output(self.event_key, ev)

    def _dr_gap(self, key: str, fix: LblFix) -> None:
        """Report the first and the last epoch of a dead-reckoning gap (fixes flagged ``degraded``)."""
        stamp = fix.header.stamp_ns
        self._degraded = fix.degraded
        if fix.degraded:
            self._gap_start_ns = stamp
            reason, level = "dr_gap", cast(Literal["info", "warning"], "warning")
            detail = f"no log or heading data for epoch {stamp} ns: values held, sigma_w inflated ({fix.status})"
        else:
            reason, level = "dr_restored", cast(Literal["info", "warning"], "info")
            detail = f"dead reckoning back after {(stamp - self._gap_start_ns) / 1e9:g} s of degraded epochs"
        report = self.config.report_events
        self.count_event(self.events, key, reason, detail, level=level, stamp_ns=stamp, report=report)


def build() -> LblNavService:
    """The service configured from ``FIXSTREAM_LBL_NAV_*`` and ``FIXSTREAM_ZENOH_*``."""
    settings = cast(LblNavSettings, LblNavSettings.load())
    return LblNavService(settings)


__all__ = ["LblNavService", "LblNavSettings", "build", "event_key", "fix_key", "input_key"]
