"""The attitude service: one instance per radar site, many targets, a thin adapter around :class:`AttitudeCore`.

decode -> validate -> :meth:`AttitudeCore.step` -> encode. Everything estimation-related (gaps, gating,
out-of-order plots, undefined angles, status) is the core's (digest 004 §5.5-§5.6); the adapter adds the
transport, the key names and the reporting. Keys (``<site>`` = ``FIXSTREAM_ATTITUDE_SITE_ID``, default the
instance name):

* in, one subscription ``fixstream/sensor/<site>/radar/<sensor>/**`` (``<sensor>`` = ``sensor_id``, default
  any): :class:`~schemas.RadarPlot` on ``.../radar/<sensor>``, :class:`~schemas.RadarSite` on
  ``.../radar/<sensor>/site`` and :class:`~schemas.TrackEnd` on ``.../radar/<sensor>/track_end`` (one key, one
  schema; any other type or key is refused as ``unexpected_type``). One subscription, so one publisher's
  messages are handled in the order they were sent;
* out: ``fixstream/fix/attitude/<site>/<target>``, one :class:`~schemas.attitude.AttitudeEstimate` per
  accepted plot (and COASTING estimates if ``coast_output``);
* ``fixstream/diag/attitude/<instance>``: every refused input with its reason, and the events below;
  ``fixstream/status/attitude/<instance>`` and ``fixstream/alive/attitude/<instance>`` (service base).

**Refused** (counted in ``rejected_by_reason``, the state is untouched): the codec's reasons (``non_finite``
for a NaN or infinite value, ``out_of_bounds``, ``bad_msgpack``, ``missing_field``, ...), ``unexpected_type``,
``invalid_target_id`` (not usable as a key chunk) and the core's ``out_of_order`` (a plot older than the
target's last), ``duplicate_time``, ``innovation_gate``, ``wrong_site``, ``bad_sigma``, ``degenerate_plot``.

**Events** (reported, not refused: the plot is used): ``scans_missed`` (info: the plot came after a gap of
more than ``coast_after_scans`` scans and was predicted over; its sigmas are wider), ``gap_reset``,
``nis_reset``, ``covariance_reset``, ``track_id_reused`` (warning: the target's state was restarted),
``heading_undefined`` / ``pitch_undefined`` / ``roll_undefined`` (warning: an angle of a converged target
became undefined, e.g. near-zero speed; the angles are null rather than wrong), ``new_target`` (info: a target
id the site has no state for, e.g. an id that changed) and ``target_evicted`` (info: no plot for
``idle_timeout_s`` of data time and no TrackEnd).

**End of a scenario.** The player's end marker (another key, so it may overtake the last plots) carries the
number of messages published per key; once that many have arrived on this site's keys the service starts a
fresh core (``reset_on_scenario_end``), so a following scenario whose stamps start again from 0 is accepted.
(The ``Service`` base waits for the announced messages; ``end_wait_s`` of quiet ends the run anyway.)

Deterministic: the outputs depend only on the order of the inputs (time comes from the stamps), and equal what
:class:`AttitudeCore` gives in-process on the same messages.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Any, ClassVar, Literal, cast

from pydantic import Field, field_validator
from pydantic_settings import SettingsConfigDict

from schemas import Message, RadarPlot, RadarSite, TrackEnd
from schemas.attitude import AttitudeEstimate
from shared import keys
from shared.service import InputRejected, Output, Service, Subscription
from shared.settings import ServiceSettings, ZenohSettings, core_config_of

from .config import AttitudeConfig
from .core import AttitudeCore
from .topics import SITE_CHUNK, TRACK_END_CHUNK

log = logging.getLogger("fixstream.attitude")

#: the estimator chunk of the output keys
ESTIMATOR = "attitude"
#: estimate flags reported as events: flag -> (reason, level)
_FLAG_EVENTS: dict[str, tuple[str, Literal["info", "warning"]]] = {
    "SCANS_MISSED": ("scans_missed", "info"),
    "GAP_RESET": ("gap_reset", "warning"),
    "NIS_RESET": ("nis_reset", "warning"),
    "COVARIANCE_RESET": ("covariance_reset", "warning"),
    "TRACK_ID_REUSED": ("track_id_reused", "warning"),
}
#: flags reported when they appear on a converged target (n_updates >= min_updates_valid) that had the angle,
#: once per target and track (roll only when the heading is defined: an undefined heading implies it)
_UNDEFINED_EVENTS = {
    "HEADING_UNDEFINED": "heading_undefined",
    "PITCH_UNDEFINED": "pitch_undefined",
    "ROLL_UNDEFINED": "roll_undefined",
}


class _TargetInfo:
    """What the adapter remembers of a target: the flags of its last estimate and the events reported."""

    __slots__ = ("flags", "key", "reported")

    def __init__(self, key: str) -> None:
        self.key = key
        self.flags: frozenset[str] | None = None
        self.reported: set[str] = set()


def input_key(site_id: str, sensor_id: str = "*") -> str:
    """``fixstream/sensor/<site>/radar/<sensor>/**``: the plots and their ``site`` and ``track_end`` keys
    (``*``: any sensor id of the site, ``.../radar/**``)."""
    base = f"{keys.ROOT}/sensor/{keys.chunk(site_id)}/radar"
    return f"{base}/**" if sensor_id == "*" else f"{base}/{keys.chunk(sensor_id)}/**"


#: the message type each key of a radar sensor carries: by the chunk after the sensor id (none: the plots)
_KEY_TYPES: dict[str | None, type] = {None: RadarPlot, SITE_CHUNK: RadarSite, TRACK_END_CHUNK: TrackEnd}


def _expected_type(key: str) -> type | None:
    """The one message type of a key ``fixstream/sensor/<site>/radar/<sensor>[/<chunk>]``; None if unknown."""
    parts = key.split("/")
    try:
        i = parts.index("radar")
    except ValueError:
        return None
    tail = parts[i + 2 :]
    if len(tail) > 1:
        return None
    return _KEY_TYPES.get(tail[0] if tail else None)


def output_key(site_id: str, target_id: str) -> str:
    """``fixstream/fix/attitude/<site>/<target>``."""
    return keys.fix(ESTIMATOR, site_id, target_id)


#: the fixed-lag smoothed estimates (``smoother_lag_scans`` > 0) go to ``<output_key>/smoothed``
SMOOTHED_SUBKEY = "smoothed"


class AttitudeSettings(ServiceSettings, AttitudeConfig):
    """``FIXSTREAM_ATTITUDE_*``: every :class:`AttitudeConfig` parameter (digest §5.2 defaults), one variable each
    (``FIXSTREAM_ATTITUDE_RADAR=Vostok3D``, ``FIXSTREAM_ATTITUDE_SIGMA_JERK_MPS3=[0.3, 0.3, 0.3]``), plus the
    instance name and the service's own options below. ``site_id`` defaults to the instance name; the one default
    that differs from the core's is ``validate_covariances`` (False)."""

    model_config = SettingsConfigDict(env_prefix="FIXSTREAM_ATTITUDE_", extra="ignore", frozen=True)

    validate_covariances: bool = Field(
        default=False,
        description="re-run the schema's symmetric-PSD check on the two output covariances before publishing; off in "
        "the service (a third of its CPU): the core keeps P Cholesky-checked and J P J^T symmetric, and every "
        "consumer validates each message on decode anyway",
    )
    sensor_id: str = Field(default="*", description="radar sensor id (last key chunk) to listen to, or *")
    report_events: bool = Field(default=True, description="report the events (resets, new targets, ...) on diag")

    @field_validator("sensor_id")
    @classmethod
    def _sensor_chunk(cls, v: str) -> str:
        return v if v == "*" else keys.chunk(v)

    @field_validator("site_id")
    @classmethod
    def _site_chunk(cls, v: str | None) -> str | None:
        return None if v is None else keys.chunk(v)

    def core_config(self, site_id: str) -> AttitudeConfig:
        """The core's configuration: the AttitudeConfig fields of these settings, for ``site_id``."""
        return core_config_of(self, AttitudeConfig, site_id=site_id)


class AttitudeService(Service):
    """Attitude of the aircraft seen by one radar site (digest 004); see the module docstring."""

    name: ClassVar[str] = "attitude"

    def __init__(self, settings: AttitudeSettings, zenoh_settings: ZenohSettings | None = None) -> None:
        super().__init__(settings, zenoh_settings)
        self.config = settings
        self.site_id = settings.site_id or self.instance
        self.core_config = settings.core_config(self.site_id)
        self.core = AttitudeCore(self.core_config)
        self.in_key = input_key(self.site_id, settings.sensor_id)
        #: per target with state: its output key and the flags of its last estimate (for the events)
        self._targets: dict[str, _TargetInfo] = {}
        self._evicted_seen = 0
        self.events: Counter[str] = Counter()
        self.outputs = 0

    # ----- Service hooks ---------------------------------------------------------------------------------------
    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.in_key, self.on_input)]

    def on_input(self, key: str, msg: Message) -> list[Output]:
        """One validated sample of the site (the base decoded it once): check its type against its key, run the
        core."""
        expected = _expected_type(key)
        if expected is None or not isinstance(msg, expected):
            want = "nothing (unknown key)" if expected is None else expected.__name__
            raise InputRejected("unexpected_type", f"{type(msg).__name__} on {key}; this key carries {want}")
        assert isinstance(msg, RadarPlot | RadarSite | TrackEnd)
        if isinstance(msg, RadarPlot) and not keys.is_chunk(msg.target_id):
            raise InputRejected("invalid_target_id", f"target id {msg.target_id!r} is not a key chunk")
        produced = self.core.step(msg)  # InputRejected propagates: the base counts and reports it
        if isinstance(msg, TrackEnd):
            self._targets.pop(msg.target_id, None)
        elif isinstance(msg, RadarPlot) and msg.target_id not in self._targets:
            self._targets[msg.target_id] = _TargetInfo(output_key(self.site_id, msg.target_id))
            if not any("TRACK_ID_REUSED" in e.flags for e in produced):  # reported as track_id_reused
                detail = f"{msg.target_id}: first plot at {msg.header.stamp_ns} ns"
                self._event(key, "new_target", detail, "info", msg.header.stamp_ns)
        out = [self._output(key, est) for est in produced]
        self._check_evictions(key, msg.header.stamp_ns)
        return out

    def new_run(self, reason: str) -> list[Output]:
        """A fresh core for the next run (its plots' stamps start again from 0)."""
        self.core = AttitudeCore(self.core_config)
        self._targets.clear()
        self._evicted_seen = 0
        return list(super().new_run(reason))

    def status_extra(self) -> dict[str, Any]:
        sigmas, scan_period_s = self.core.site_parameters(self.site_id)
        return {
            "site_id": self.site_id,
            "keys": {"in": self.in_key, "out": f"{keys.fix(ESTIMATOR, self.site_id)}/*"},
            "targets": len(self.core.targets()),
            "sigmas": sigmas.model_dump(),
            "scan_period_s": scan_period_s,
            "core": dict(self.core.counters),
            "events": dict(self.events),
            "outputs": self.outputs,
            "sessions": self.sessions,
        }

    # ----- internals -------------------------------------------------------------------------------------------
    def _output(self, key: str, est: AttitudeEstimate) -> Output:
        tid = est.target_id
        info = self._targets.get(tid)
        if info is None:
            info = self._targets[tid] = _TargetInfo(output_key(self.site_id, tid))
        if "SMOOTHED" in est.flags:  # the fixed-lag smoothed estimate (smoother_lag_scans): its own key, no events
            self.outputs += 1
            return Output(f"{info.key}/{SMOOTHED_SUBKEY}", est)
        flags = frozenset(est.flags)
        previous, info.flags = info.flags, flags
        if est.status == "RESET":
            info.reported.clear()
        self.outputs += 1
        if flags:  # events are counted always, reported if report_events
            for flag, (reason, level) in _FLAG_EVENTS.items():
                if flag in flags:
                    self._event(
                        key, reason, f"{tid}: {est.status} at {est.header.stamp_ns} ns", level, est.header.stamp_ns
                    )
            if previous is not None and est.n_updates >= self.core_config.min_updates_valid:
                for flag, reason in _UNDEFINED_EVENTS.items():
                    rising = flag in flags and flag not in previous and reason not in info.reported
                    if rising and not (flag == "ROLL_UNDEFINED" and "HEADING_UNDEFINED" in flags):
                        info.reported.add(reason)
                        speed = "?" if est.speed_mps is None else f"{est.speed_mps:.1f}"
                        self._event(
                            key,
                            reason,
                            f"{tid}: speed {speed} m/s at {est.header.stamp_ns} ns",
                            "warning",
                            est.header.stamp_ns,
                        )
        return Output(info.key, est)

    def _event(self, key: str, reason: str, detail: str, level: Literal["info", "warning"], stamp_ns: int) -> None:
        self.count_event(
            self.events, key, reason, detail, level=level, stamp_ns=stamp_ns, report=self.config.report_events
        )

    def _check_evictions(self, key: str, stamp_ns: int) -> None:
        """Report targets the core evicted for idleness (they disappeared without a TrackEnd)."""
        evicted = self.core.counters["evicted_idle"]
        if evicted == self._evicted_seen:
            return
        self._evicted_seen = evicted
        alive = {tid for _, tid in self.core.targets()}
        for tid in [t for t in self._targets if t not in alive]:
            del self._targets[tid]
            self.events["target_evicted"] += 1
            if self.config.report_events:
                self.report(
                    key,
                    "target_evicted",
                    f"{tid}: no plot for {self.core_config.idle_timeout_s:g} s and no TrackEnd",
                    count=self.events["target_evicted"],
                    counts=dict(self.events),
                    level="info",
                    stamp_ns=stamp_ns,
                )


def build() -> AttitudeService:
    """The service configured from ``FIXSTREAM_ATTITUDE_*`` and ``FIXSTREAM_ZENOH_*``."""
    settings = cast(AttitudeSettings, AttitudeSettings.load())
    return AttitudeService(settings)


__all__ = ["SMOOTHED_SUBKEY", "AttitudeService", "AttitudeSettings", "build", "input_key", "output_key"]
