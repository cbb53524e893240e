"""The terrain-navigation service: one instance per vehicle, a thin adapter around :class:`TerrainNavigator`.

decode -> validate -> per-key stamp check -> reorder buffer -> core ``step`` -> encode. Everything
estimation-related is the core's; the adapter adds only the transport.

Keys (``<vehicle>`` = ``FIXSTREAM_TERRAIN_NAV_VEHICLE``, default the instance name):

* in, one subscription ``fixstream/sensor/<vehicle>/**``: ``.../ins/<id>`` (:class:`InsSample`),
  ``.../radalt/<id>`` (:class:`RadioAltimeter`), ``.../baro/<id>`` (:class:`BaroAltitude`) and
  ``.../reset/<id>`` (:class:`NavReset`), ``<id>`` any unless configured. Other sensors of the vehicle are
  ignored (counted in the base's ``counters.ignored``, never validated). One subscription, because Zenoh runs
  each subscriber's callbacks on its own thread: two subscribers may interleave one publisher's messages out of
  order;
* out: ``fixstream/fix/terrain/<vehicle>`` (:class:`TerrainFix`, after each valid verdict) and
  ``fixstream/fix/terrain/<vehicle>/verdict`` (:class:`TerrainVerdict`: every evaluation and the status
  verdicts ``OUT_OF_ZONE``, ``GAP``, ``RESET``);
* ``fixstream/diag/terrain_nav/<instance>``: every refused input with its reason (the codec's reasons such
  as ``bad_msgpack`` or ``non_finite``, ``unexpected_type``, ``stamp_backwards``, and the core's
  ``ra_invalid``, ``ins_invalid``, ``baro_invalid``, ``stamp_not_increasing``, ``unsynchronised``), plus the
  events ``ins_gap`` and ``out_of_zone`` (reported, not refused: the message that revealed them is used).

**Reorder buffer (digest §5.5).** Inputs from different publishers may arrive interleaved out of stamp
order. Accepted messages wait in a buffer ordered by stamp (equal stamps: INS, baro, radio altimeter,
reset, then arrival) and go to the core once the newest stamp seen is ``reorder_s`` (0.1 s) past theirs.
For input that arrives in that order (the player's) the core sees exactly that order, and the outputs
equal those of the core run in-process on the same messages.

**End of a scenario.** Once every message the player's end marker announced on the vehicle's keys has
arrived (the ``Service`` base waits for them), the service releases the buffer and, with
``reset_on_scenario_end``, starts a fresh session (a ``RESET`` verdict), so the next scenario's stamps,
which start again from 0, are accepted. ``idle_flush_s`` of wall-clock quiet, and stopping, release what
is left.

**Counters.** The base's ``received = accepted + rejected`` holds: a buffered message counts as accepted
until the core refuses it, which moves it to ``rejected`` under the core's reason. ``status_extra`` adds
``pending`` (in the buffer), the core's own counters, ``events`` (``ins_gap``, ``out_of_zone``,
``late``: arrived behind the buffer), ``outputs``, ``sessions`` and the last verdict.
"""

from __future__ import annotations

import heapq
import logging
import time
from collections import Counter
from collections.abc import Iterable
from typing import Any, ClassVar, Literal, cast

from pydantic import Field, field_validator, model_validator
from pydantic_settings import SettingsConfigDict

from schemas import BaroAltitude, InsSample, Message, NavReset, RadioAltimeter, ScenarioMarker
from schemas.terrain_nav import TerrainFix, TerrainVerdict
from shared import keys
from shared.service import InputRejected, Output, Service, Subscription
from shared.settings import ServiceSettings, ZenohSettings

from .config import TerrainNavConfig
from .core import Evaluation, TerrainNavigator
from .maps import ReferenceMap, load_map, resolve_map_path
from .topics import BARO_KIND, INS_KIND, RADALT_KIND, RESET_KIND

log = logging.getLogger("fixstream.terrain_nav")

#: the estimator chunk of the output keys: ``fixstream/fix/terrain/<vehicle>``
ESTIMATOR = "terrain"
VERDICT_SUFFIX = "verdict"
#: order of messages with equal stamps in the reorder buffer: the INS (and baro) before the RA they synchronise
_RANK: dict[type[Message], int] = {InsSample: 0, BaroAltitude: 1, RadioAltimeter: 2, NavReset: 3}


def _sensor_chunk(v: str) -> str:
    return v if v == "*" else keys.chunk(v)


class TerrainNavSettings(ServiceSettings):
    """``FIXSTREAM_TERRAIN_NAV_*``; the estimator's parameters nest under ``CORE__`` (digest §6 defaults)."""

    model_config = SettingsConfigDict(env_prefix="FIXSTREAM_TERRAIN_NAV_", extra="ignore", env_nested_delimiter="__")

    vehicle: keys.Chunk | None = Field(default=None, description="vehicle id in the keys (default: the instance name)")
    map_path: str = Field(min_length=1, description="reference map: .npy with a .json sidecar, or a GeoTIFF")
    map_cell_m: float | None = Field(default=None, gt=0.0, description="block-average the map to this cell, m")
    map_x_axis: Literal["north", "east"] = Field(default="north", description="GeoTIFF: map x along north or east")
    ins_sensor: str = Field(default="*", description="INS sensor id (last key chunk) or *")
    radalt_sensor: str = Field(default="*", description="radio-altimeter sensor id or *")
    baro_sensor: str = Field(default="*", description="barometric-altitude sensor id or *")
    reset_sensor: str = Field(default="*", description="reset source id or *")
    reorder_s: float = Field(default=0.1, ge=0.0, le=10.0, description="reorder buffer, s of data (§5.5)")
    idle_flush_s: float = Field(
        default=2.0, ge=0.0, description="release the buffer after this much wall-clock quiet, s (0: never)"
    )
    core: TerrainNavConfig = Field(default_factory=TerrainNavConfig, description="the estimator's parameters")
    preset: Literal["paper", "robust"] | None = Field(
        default=None,
        description="the estimator's preset, as FIXSTREAM_<ESTIMATOR>_PRESET of the other estimators: the same as"
        " CORE__PRESET (compose reads FIXSTREAM_TERRAIN_NAV_PRESET for it); both, with different values: an error",
    )

    @model_validator(mode="before")
    @classmethod
    def _preset_shorthand(cls, data: Any) -> Any:
        """``preset`` goes into the core before it is built, so that it fills what the core was not given."""
        if not isinstance(data, dict) or data.get("preset") is None:
            return data
        core = data.get("core")
        core = dict(core) if isinstance(core, dict) else {}
        if core.get("preset") not in (None, data["preset"]):
            raise ValueError(f"preset {data['preset']!r} and core.preset {core['preset']!r} disagree: give one")
        return {**data, "core": {**core, "preset": data["preset"]}}

    @field_validator("ins_sensor", "radalt_sensor", "baro_sensor", "reset_sensor")
    @classmethod
    def _chunk_or_star(cls, v: str) -> str:
        return _sensor_chunk(v)


class ReorderBuffer:
    """Messages ordered by (stamp, rank, arrival), released once the newest stamp is ``horizon_ns`` past theirs.

    ``rank`` orders messages with equal stamps independently of their arrival (the service ranks INS, baro,
    radio altimeter, reset), so that within the horizon the order depends on the data only.
    """

    def __init__(self, horizon_ns: int) -> None:
        self.horizon_ns = horizon_ns
        self._heap: list[tuple[int, int, int, str, Message]] = []
        self._n = 0
        self.newest_ns: int | None = None
        #: stamp of the last message released (a later arrival behind it is "late")
        self.released_ns: int | None = None

    def __len__(self) -> int:
        return len(self._heap)

    def push(self, stamp_ns: int, key: str, msg: Message, rank: int = 0) -> bool:
        """Queue a message; False if it arrived behind what was already released (it is still queued)."""
        heapq.heappush(self._heap, (stamp_ns, rank, self._n, key, msg))
        self._n += 1
        if self.newest_ns is None or stamp_ns > self.newest_ns:
            self.newest_ns = stamp_ns
        return self.released_ns is None or stamp_ns >= self.released_ns

    def pop_ready(self) -> list[tuple[str, Message]]:
        if self.newest_ns is None:
            return []
        return self._pop_until(self.newest_ns - self.horizon_ns)

    def drain(self) -> list[tuple[str, Message]]:
        return self._pop_until(None)

    def _pop_until(self, limit_ns: int | None) -> list[tuple[str, Message]]:
        out: list[tuple[str, Message]] = []
        heap = self._heap
        while heap and (limit_ns is None or heap[0][0] <= limit_ns):
            stamp, _, _, key, msg = heapq.heappop(heap)
            out.append((key, msg))
            self.released_ns = stamp if self.released_ns is None else max(self.released_ns, stamp)
        return out

    def clear(self) -> None:
        self._heap.clear()
        self.newest_ns = None
        self.released_ns = None


class TerrainNavService(Service):
    """Terrain-aided navigation of one vehicle (digest 001); see the module docstring."""

    name: ClassVar[str] = "terrain_nav"

    def __init__(
        self,
        settings: TerrainNavSettings,
        zenoh_settings: ZenohSettings | None = None,
        ref_map: ReferenceMap | None = None,
    ) -> None:
        super().__init__(settings, zenoh_settings)
        self.config = settings
        self.vehicle = settings.vehicle or self.instance
        self.map_file = resolve_map_path(settings.map_path)
        self.ref_map = (
            ref_map if ref_map is not None else load_map(self.map_file, settings.map_cell_m, settings.map_x_axis)
        )
        self.nav = TerrainNavigator(self.ref_map, settings.core, source=self.source)
        # a derived N_min/N_max is computed once; later sessions reuse it
        self.core_config = settings.core
        if settings.core.derive_n_limits:
            self.core_config = settings.core.model_copy(
                update={"derive_n_limits": False, "N_min": self.nav.N_min, "N_max": self.nav.N_max}
            )
        self.fix_key = keys.fix(ESTIMATOR, self.vehicle)
        self.verdict_key = keys.fix(ESTIMATOR, self.vehicle, VERDICT_SUFFIX)
        self.buffer = ReorderBuffer(round(settings.reorder_s * 1e9))
        self._prefix = f"{keys.ROOT}/sensor/{self.vehicle}/"
        self._kinds: dict[str, type[Message]] = {
            INS_KIND: InsSample,
            RADALT_KIND: RadioAltimeter,
            BARO_KIND: BaroAltitude,
            RESET_KIND: NavReset,
        }
        self._sensor_ids = {
            INS_KIND: settings.ins_sensor,
            RADALT_KIND: settings.radalt_sensor,
            BARO_KIND: settings.baro_sensor,
            RESET_KIND: settings.reset_sensor,
        }
        self._last_stamp: dict[str, int] = {}
        self._last_input_wall = time.monotonic()
        self.events: Counter[str] = Counter()
        self.outputs: Counter[str] = Counter()
        self.last_verdict: dict[str, Any] | None = None

    # ----- Service hooks ---------------------------------------------------------------------------------------
    def subscriptions(self) -> list[Subscription]:
        return [Subscription(f"{self._prefix}**", self.on_input, accepts=self.types_on)]

    def types_on(self, key: str) -> tuple[type[Message], ...] | None:
        """The message type the vehicle's ``key`` carries, or None for a sensor this service does not read (the base
        counts it as ignored, unvalidated)."""
        parts = key.split("/")
        model = self._kinds.get(parts[3]) if len(parts) == 5 else None
        wanted = self._sensor_ids.get(parts[3], "*") if model is not None else ""
        if model is None or wanted not in ("*", parts[4]):
            return None
        return (model,)

    def on_input(self, key: str, msg: Message) -> list[Output]:
        """One validated sample of the vehicle (the base decoded it once and checked its type against
        :meth:`types_on`): per-key stamp check, then the reorder buffer; returns what the released messages produced."""
        self._last_input_wall = time.monotonic()
        stamp = msg.header.stamp_ns
        last = self._last_stamp.get(key)
        if last is not None and stamp < last:
            raise InputRejected("stamp_backwards", f"stamp {stamp} ns < last {last} ns on {key}")
        self._last_stamp[key] = stamp
        if not self.buffer.push(stamp, key, msg, _RANK.get(type(msg), len(_RANK))):
            self.events["late"] += 1
        return self._release(self.buffer.pop_ready())

    def flush_run(self, marker: ScenarioMarker) -> list[Output]:
        """Every message of the scenario has arrived: release the buffer."""
        return self._release(self.buffer.drain())

    def on_idle(self) -> list[Output]:
        """Wall-clock housekeeping: after ``idle_flush_s`` without input, release the buffer."""
        wait = self.config.idle_flush_s
        if wait <= 0 or time.monotonic() - self._last_input_wall < wait:
            return []
        return self._release(self.buffer.drain()) if len(self.buffer) else []

    def on_stop(self) -> None:
        """Stopping: what is still buffered goes out before the session closes."""
        for out in self._release(self.buffer.drain()):
            self.publish(out.key, out.msg)

    def status_extra(self) -> dict[str, Any]:
        ref = self.ref_map
        return {
            "vehicle": self.vehicle,
            "keys": {"fix": self.fix_key, "verdict": self.verdict_key},
            "map": {
                "path": str(self.map_file),
                "shape": list(ref.shape),
                "cell_m": ref.cell_m,
                "D1_m2": ref.D1_m2,
                "zone_cells": int(self.nav.zone.sum()),
            },
            "n_limits": [self.nav.N_min, self.nav.N_max],
            "pending": len(self.buffer),
            "sessions": self.sessions,
            "events": dict(self.events),
            "outputs": dict(self.outputs),
            "core": dict(self.nav.counters),
            "last_verdict": self.last_verdict,
        }

    # ----- internals ----------------------------------------------------------------------------------------------
    def _release(self, items: Iterable[tuple[str, Message]]) -> list[Output]:
        out: list[Output] = []
        for key, msg in items:
            try:
                produced = self.nav.step(msg)
            except InputRejected as exc:
                # it was counted as accepted when it entered the buffer: it is a rejection after all
                self.counters.accepted -= 1
                self.reject(key, exc.reason, exc.detail, stamp_ns=msg.header.stamp_ns)
                continue
            for m in produced:
                out.append(self._output(key, m))
        return out

    def _output(self, key: str, m: Message) -> Output:
        if isinstance(m, TerrainFix):
            self.outputs["fixes"] += 1
            return Output(self.fix_key, m)
        v = cast(TerrainVerdict, m)
        self.outputs["verdicts"] += 1
        self.last_verdict = {"state": v.state, "stamp_ns": v.header.stamp_ns, "n_valid": v.n_valid}
        if v.state in ("GAP", "OUT_OF_ZONE"):
            reason = "ins_gap" if v.state == "GAP" else "out_of_zone"
            self.count_event(self.events, key, reason, v.detail, stamp_ns=v.header.stamp_ns)
        return Output(self.verdict_key, v)

    def new_run(self, reason: str) -> list[Output]:
        """A new session for the next run, announced by a ``RESET`` verdict."""
        last_ns = self.buffer.released_ns or 0
        ev = Evaluation(t=last_ns * 1e-9, state="RESET", detail=reason[:256])
        verdict = self.nav.verdict_message(ev)
        self.nav = TerrainNavigator(self.ref_map, self.core_config, source=self.source)
        self.buffer.clear()
        self._last_stamp.clear()
        super().new_run(reason)
        return [self._output("", verdict)]


def build() -> TerrainNavService:
    """The service configured from ``FIXSTREAM_TERRAIN_NAV_*`` and ``FIXSTREAM_ZENOH_*``."""
    settings = cast(TerrainNavSettings, TerrainNavSettings.load())
    return TerrainNavService(settings)


__all__ = ["ReorderBuffer", "TerrainNavService", "TerrainNavSettings", "build"]
