"""Player plugin ``lbl_nav``: an AUV with a water-relative log, a compass and one-way LBL ranges (digest 000).

Wraps the core's pure simulation (:func:`services.lbl_nav.simulation.simulate`): the truth is integrated both
ways from the launch point with the true ground velocity (log on the true heading + known current + its error),
and every error process of the digest's section 1 is drawn with the paper's sigmas and correlation times —
constant sound-speed error Δc, common and independent range errors δ and v, white log noise, Markov heading and
current errors — with visibility by horizontal range (before launch only ``pre_launch_beacons``, at the launch
epoch exactly ``launch_beacons``). ``preset`` picks the digest's scenario (``s1`` simulation replica, ``s2``
field-like replica, ``s3`` geometry sweep at ``s3_angle_deg``); every other field, when given, overrides the
preset's value.

``track`` (:class:`~services.player.simulators.recorded_track.TrackFileParams`) takes the truth from a recorded
trajectory file instead of the synthetic motion (docs/scenarios.md, "Trajectory files"): the epochs run from the
track's first row (``track.time_offset_s``) every ``dt_s`` to its end, the launch epoch is ``pre_launch_s`` after
the first, and the log, heading, depth and ranges are made from the recorded positions, heading and depth
(:func:`services.lbl_nav.simulation.simulate`, ``path``). It excludes the motion fields (``start_s``,
``post_launch_s``, ``launch_xy_m``, ``heading_knots``, ``speed_mps``, ``v_starboard_mps``, ``auv_depth_m``,
``yaw_*``).

``dropouts`` silence a stream (log, heading, depth or ranges) for an interval of the scenario clock.

Time: the first epoch is at ``start_s`` on the scenario clock and the launch epoch (two beacons heard) at
``start_s + pre_launch_s``; epochs every ``dt_s`` until ``post_launch_s`` after launch. Events after the
scenario's ``duration_s`` are not published (a shorter scenario cuts the run).

Keys (``<v>`` = ``platform``), all under the vehicle's sensor prefix so that one subscription of the estimator
keeps their order:

* ``fixstream/sensor/<v>/lbl/beacons``: one :class:`~schemas.BeaconTable` at the first epoch;
* ``fixstream/sensor/<v>/current/model0``: the known current (:class:`~schemas.Current`) at the first epoch;
* per epoch: ``.../speed_log/log0`` (:class:`~schemas.SpeedLog`, V^ξ and V^η), ``.../heading/compass0``
  (:class:`~schemas.Heading`, measured = true − ΔK), ``.../depth/depth0`` (:class:`~schemas.Depth`) and on
  ``.../lbl/rx0`` one :class:`~schemas.BeaconRange` per visible beacon (``range_m``, or ``travel_time_s`` with
  ``ranges_as_travel_time``);
* ``fixstream/truth/<v>`` (unless ``publish_truth: false``) before the sensors of each epoch: position
  ``[east, north, -depth]`` in the scenario frame, ground velocity, ``attitude_rad`` = [true heading, 0, 0] and
  ``extra``: ``dK_rad``, ``dU_north_mps``, ``dU_east_mps``, ``dc_mps``, ``depth_m``, ``t_from_launch_s`` and
  ``beacons_visible``.

The vehicle's trajectory is registered in the scenario context under ``platform``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import replace
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, Field, model_validator

from schemas import BeaconRange, BeaconTable, Current, Depth, Heading, Message, SpeedLog, Truth
from services.player.simulators import NS_PER_S, Event, ScenarioContext, SimParams, TruthState, register
from services.player.simulators.recorded_track import RecordedTrack, TrackFileParams, load_cached
from shared import keys

from .simulation import RecordedPath, ScenarioSpec, SimBeacon, SimRun, s1_spec, s2_spec, s3_spec, simulate

KeyChunk = Annotated[str, AfterValidator(keys.chunk)]
Pair = Annotated[list[float], Field(min_length=2, max_length=2)]
Triple = Annotated[list[float], Field(min_length=3, max_length=3)]

#: key kinds and sensor ids under fixstream/sensor/<vehicle>/
RANGES = ("lbl", "rx0")
TABLE = ("lbl", "beacons")
LOG = ("speed_log", "log0")
HEADING = ("heading", "compass0")
DEPTH = ("depth", "depth0")
CURRENT = ("current", "model0")


#: the message types published on the sensor keys
SENSOR_TYPES: tuple[type[Message], ...] = (BeaconTable, Current, SpeedLog, Heading, Depth, BeaconRange)


def sensor_keys(vehicle: str) -> dict[str, str]:
    """The keys the plugin publishes a vehicle's messages on, by message type name."""
    return {
        "BeaconTable": keys.sensor(vehicle, *TABLE),
        "Current": keys.sensor(vehicle, *CURRENT),
        "SpeedLog": keys.sensor(vehicle, *LOG),
        "Heading": keys.sensor(vehicle, *HEADING),
        "Depth": keys.sensor(vehicle, *DEPTH),
        "BeaconRange": keys.sensor(vehicle, *RANGES),
    }


class DropoutParams(SimParams):
    """A stream that publishes nothing for a while (a sensor failure), on the scenario clock."""

    stream: Literal["log", "heading", "depth", "ranges"] = Field(description="SpeedLog, Heading, Depth or BeaconRange")
    start_s: float = Field(ge=0.0, le=1e7, description="scenario time of the first missing sample, s")
    duration_s: float = Field(gt=0.0, le=1e7, description="s; samples stamped in [start_s, start_s + duration_s)")


_DROPOUT_TYPES: dict[str, type[Message]] = {
    "log": SpeedLog,
    "heading": Heading,
    "depth": Depth,
    "ranges": BeaconRange,
}


class BeaconParams(SimParams):
    """One beacon: id and position in the scenario frame (x east, y north, depth positive down)."""

    id: KeyChunk = Field(description="beacon id (BeaconRange.beacon_id)")
    x_east_m: float = Field(ge=-1e6, le=1e6, description="m")
    y_north_m: float = Field(ge=-1e6, le=1e6, description="m")
    depth_m: float = Field(ge=0.0, le=11_000.0, description="m, positive down")


PRESETS: dict[str, ScenarioSpec] = {"s1": s1_spec(), "s2": s2_spec()}
#: the fields of the synthetic motion, which a recorded track replaces
MOTION_FIELDS = (
    "post_launch_s",
    "launch_xy_m",
    "heading_knots",
    "speed_mps",
    "v_starboard_mps",
    "auv_depth_m",
    "yaw_amplitude_deg",
    "yaw_period_s",
    "yaw_bumps",
)


class LblSimParams(SimParams):
    """Parameters of ``lbl_nav``. Every field left out (None) takes the preset's value (digest section 4.4)."""

    platform: KeyChunk = Field(default="lbl1", description="vehicle id: keys fixstream/sensor/<platform>/...")
    preset: Literal["s1", "s2", "s3"] = Field(
        default="s1",
        description="s1: simulation replica (5 m/s, turn before launch, 10 deg to the line, turn after; N = 360); "
        "s2: field-like (4 m/s, 35 deg, yaw, N = 97, no heading/current error); s3: straight at s3_angle_deg",
    )
    s3_angle_deg: float = Field(default=30.0, ge=-360.0, le=360.0, description="s3: track angle to the beacon line")
    start_s: float = Field(default=0.0, ge=0.0, le=1e6, description="scenario time of the first epoch, s")
    pre_launch_s: float | None = Field(
        default=None, gt=0.0, le=1e5, description="time from the first epoch to launch (N dt), s; preset 360 / 97"
    )
    post_launch_s: float | None = Field(default=None, ge=0.0, le=1e6, description="time after launch, s")
    dt_s: float | None = Field(default=None, gt=0.0, le=60.0, description="epoch period, s")
    beacons: list[BeaconParams] | None = Field(default=None, min_length=1, max_length=256)
    pre_launch_beacons: list[KeyChunk] | None = Field(default=None, description="beacons heard before launch")
    launch_beacons: list[KeyChunk] | None = Field(default=None, min_length=2, description="heard at launch")
    launch_xy_m: Pair | None = Field(default=None, description="[east, north] of the vehicle at launch, m")
    heading_knots: list[Pair] | None = Field(
        default=None,
        min_length=1,
        max_length=10_000,
        description="[t from launch s, true heading deg], piecewise linear, constant outside (unwrapped degrees)",
    )
    speed_mps: float | None = Field(default=None, ge=0.0, le=20.0, description="speed through the water, m/s")
    v_starboard_mps: float | None = Field(default=None, ge=-5.0, le=5.0, description="sway, + starboard, m/s")
    auv_depth_m: float | None = Field(default=None, ge=0.0, le=11_000.0, description="vehicle depth, m")
    yaw_amplitude_deg: float | None = Field(default=None, ge=0.0, le=90.0, description="sinusoidal yaw, deg")
    yaw_period_s: float | None = Field(default=None, gt=0.0, le=1e5, description="yaw period, s")
    yaw_bumps: list[Triple] | None = Field(
        default=None, max_length=1000, description="[centre s, half-width s, peak deg] triangular heading bumps"
    )
    reception_m: float | None = Field(default=None, gt=0.0, le=1e5, description="horizontal reception range, m")
    known_current_ne_mps: Pair | None = Field(default=None, description="[north, east] known current, m/s")
    c_nominal_mps: float | None = Field(default=None, gt=1000.0, lt=2000.0, description="assumed sound speed c~")
    sigma_delta_m: float | None = Field(default=None, ge=0.0, le=1000.0, description="common range error, m")
    sigma_v_m: float | None = Field(default=None, ge=0.0, le=1000.0, description="independent range error, m")
    sigma_dc_mps: float | None = Field(default=None, ge=0.0, le=100.0, description="sound-speed error, m/s")
    sigma_dV_mps: float | None = Field(default=None, ge=0.0, le=10.0, description="log noise (1-s average), m/s")  # noqa: N815
    sigma_dK_deg: float | None = Field(default=None, ge=0.0, le=90.0, description="heading error (Markov), deg")  # noqa: N815
    sigma_dU_mps: float | None = Field(default=None, ge=0.0, le=10.0, description="current error (Markov), m/s")  # noqa: N815
    tau_dK_s: float | None = Field(default=None, gt=0.0, le=1e7, description="heading error correlation, s")  # noqa: N815
    tau_dU_s: float | None = Field(default=None, gt=0.0, le=1e7, description="current error correlation, s")  # noqa: N815
    ranges_as_travel_time: bool | None = Field(default=None, description="publish travel_time_s instead of range_m")
    publish_truth: bool = Field(default=True, description="publish Truth on fixstream/truth/<platform>")
    dropouts: list[DropoutParams] = Field(default_factory=list, max_length=1000, description="sensor outages")
    track: TrackFileParams | None = Field(
        default=None, description="truth from a recorded trajectory file instead of the synthetic motion"
    )

    @model_validator(mode="after")
    def _check(self) -> LblSimParams:
        if self.track is not None:
            given = [f for f in MOTION_FIELDS if getattr(self, f) is not None]
            given += ["start_s"] if "start_s" in self.model_fields_set else []
            if given:
                raise ValueError(
                    f"track replaces the synthetic motion: remove {', '.join(given)} "
                    "(the epochs start at track.time_offset_s and end with the track)"
                )
        spec = self.spec()
        if spec.t_end_s < 0.0:
            raise ValueError(f"pre_launch_s {-spec.t_start_s:g} s is longer than the recorded track")
        n_pre = -spec.t_start_s / spec.dt_s
        if abs(n_pre - round(n_pre)) > 1e-9 or abs(spec.t_end_s / spec.dt_s - round(spec.t_end_s / spec.dt_s)) > 1e-9:
            raise ValueError("pre_launch_s and post_launch_s must be multiples of dt_s")
        ids = [b.beacon_id for b in spec.beacons]
        if len(set(ids)) != len(ids):
            raise ValueError("beacons: duplicate beacon id")
        for name in ("pre_launch_beacons", "launch_beacons"):
            unknown = [b for b in getattr(spec, name) if b not in ids]
            if unknown:
                raise ValueError(f"{name}: unknown beacon(s) {unknown}")
        if len(set(spec.launch_beacons)) < 2:
            raise ValueError("launch_beacons: at least two distinct beacons are heard at launch")
        return self

    def spec(self) -> ScenarioSpec:
        """The simulation's ScenarioSpec: the preset with the given fields replaced (times on the scenario clock)."""
        base = s3_spec(self.s3_angle_deg) if self.preset == "s3" else PRESETS[self.preset]
        upd: dict[str, Any] = {"name": f"{self.preset.upper()}:{self.platform}", "platform": self.platform}
        for name in (
            "dt_s",
            "speed_mps",
            "v_starboard_mps",
            "auv_depth_m",
            "yaw_amplitude_deg",
            "yaw_period_s",
            "reception_m",
            "c_nominal_mps",
            "sigma_delta_m",
            "sigma_v_m",
            "sigma_dc_mps",
            "sigma_dV_mps",
            "sigma_dK_deg",
            "sigma_dU_mps",
            "tau_dK_s",
            "tau_dU_s",
            "ranges_as_travel_time",
        ):
            value = getattr(self, name)
            if value is not None:
                upd[name] = value
        if self.pre_launch_s is not None:
            upd["t_start_s"] = -self.pre_launch_s
        if self.post_launch_s is not None:
            upd["t_end_s"] = self.post_launch_s
        if self.beacons is not None:
            upd["beacons"] = tuple(SimBeacon(b.id, b.x_east_m, b.y_north_m, b.depth_m) for b in self.beacons)
        if self.pre_launch_beacons is not None:
            upd["pre_launch_beacons"] = tuple(self.pre_launch_beacons)
        if self.launch_beacons is not None:
            upd["launch_beacons"] = tuple(self.launch_beacons)
        if self.launch_xy_m is not None:
            upd["launch_xy_m"] = (self.launch_xy_m[0], self.launch_xy_m[1])
        if self.heading_knots is not None:
            upd["heading_knots"] = tuple((k[0], k[1]) for k in self.heading_knots)
        if self.yaw_bumps is not None:
            upd["yaw_bumps"] = tuple((b[0], b[1], b[2]) for b in self.yaw_bumps)
        if self.known_current_ne_mps is not None:
            upd["known_current_ne_mps"] = (self.known_current_ne_mps[0], self.known_current_ne_mps[1])
        spec = replace(base, **upd)
        if self.track is not None:
            track = load_cached(self.track)
            span = math.floor((track.end_s - track.start_s) / spec.dt_s + 1e-9) * spec.dt_s
            return replace(spec, t_end_s=span + spec.t_start_s, epoch0_s=track.start_s - spec.t_start_s)
        return replace(spec, epoch0_s=self.start_s - spec.t_start_s)

    @property
    def launch_s(self) -> float:
        """Scenario time of the launch epoch (two beacons heard), s."""
        return self.spec().epoch0_s

    @property
    def end_s(self) -> float:
        """Scenario time of the last epoch, s."""
        spec = self.spec()
        return spec.epoch0_s + spec.t_end_s


class SimTruth:
    """Exact truth of the simulated vehicle (a :class:`~services.player.simulators.TruthSource`): positions
    linear between epochs, the ground velocity and true heading of the interval that ends at the next epoch."""

    def __init__(self, run: SimRun) -> None:
        sp = run.spec
        self.t_ns = run.stamps_ns.astype(np.float64)
        self.pos = np.column_stack([run.x_m, run.y_m, np.full(run.x_m.size, -sp.auv_depth_m)])
        vel = np.zeros_like(self.pos)
        if run.x_m.size > 1:
            vel[1:, 0] = np.diff(run.x_m) / sp.dt_s
            vel[1:, 1] = np.diff(run.y_m) / sp.dt_s
            vel[0] = vel[1]
        self.vel = vel
        self.heading = np.mod(run.heading_true_rad, 2.0 * math.pi)

    def truth_at(self, stamps_ns: np.ndarray) -> TruthState:
        s = np.asarray(stamps_ns, dtype=np.float64)
        pos = np.column_stack([np.interp(s, self.t_ns, self.pos[:, j]) for j in range(3)])
        i = np.clip(np.searchsorted(self.t_ns, s, side="left"), 0, self.t_ns.size - 1)
        zeros = np.zeros(s.size)
        return TruthState(pos, self.vel[i], self.heading[i], zeros, zeros.copy())

    def pitch_roll(self, i: int) -> tuple[float, float]:
        """Pitch and roll at epoch i (rad): a synthetic AUV flies level."""
        return (0.0, 0.0)


class TrackTruth(SimTruth):
    """Truth at the epochs of a recorded track: its positions, velocity and attitude (the simulator registers
    the track itself as the platform's truth source)."""

    def __init__(self, track: RecordedTrack, run: SimRun) -> None:
        st = track.states(run.stamps_ns / NS_PER_S)
        self.t_ns = run.stamps_ns.astype(np.float64)
        self.pos = st.position_m
        self.vel = st.velocity_mps
        self.heading = np.mod(run.heading_true_rad, 2.0 * math.pi)
        self.pitch = st.pitch_rad
        self.roll = st.roll_rad

    def pitch_roll(self, i: int) -> tuple[float, float]:
        return (float(self.pitch[i]), float(self.roll[i]))


def recorded_path(track: RecordedTrack, spec: ScenarioSpec) -> RecordedPath:
    """The track at the epochs of ``spec`` (scenario times ``epoch0_s + t``)."""
    n0 = round(-spec.t_start_s / spec.dt_s)
    k = np.arange(round((spec.t_end_s - spec.t_start_s) / spec.dt_s) + 1) - n0
    st = track.states(np.asarray(spec.epoch0_s + k * spec.dt_s, dtype=np.float64))
    p, v = st.position_m, st.velocity_mps
    return RecordedPath(p[:, 0], p[:, 1], -p[:, 2], st.heading_rad, (float(v[0, 0]), float(v[0, 1])))


@register("lbl_nav")
class LblNavSimulator:
    """Sensor and truth streams of one AUV in a sparse LBL field; see the module docstring."""

    Params = LblSimParams

    def __init__(self, params: LblSimParams, rng: np.random.Generator, context: ScenarioContext) -> None:
        self.params = params
        self.context = context
        self.spec = params.spec()
        self.track: RecordedTrack | None = None
        path = None
        if params.track is not None:
            self.track = load_cached(params.track)
            path = recorded_path(self.track, self.spec)
        self.run = simulate(self.spec, rng, context.seed, header=lambda stamp, _i: context.header(stamp), path=path)
        self.truth = SimTruth(self.run) if self.track is None else TrackTruth(self.track, self.run)
        context.register_platform(params.platform, self.track if self.track is not None else self.truth)
        self.keys = sensor_keys(params.platform)
        self.truth_key = keys.truth(params.platform)

    def _truth(self, i: int, stamp: int) -> Truth:
        run, sp = self.run, self.spec
        return Truth(
            header=self.context.header(stamp),
            platform=self.params.platform,
            position_m=self.truth.pos[i].tolist(),
            velocity_mps=self.truth.vel[i].tolist(),
            attitude_rad=[float(self.truth.heading[i]), *self.truth.pitch_roll(i)],
            extra={
                "dK_rad": float(run.dK_rad[i]),
                "dU_north_mps": float(run.dU_north_mps[i]),
                "dU_east_mps": float(run.dU_east_mps[i]),
                "dc_mps": float(run.dc_mps),
                "depth_m": float(sp.auv_depth_m) if self.track is None else -float(self.truth.pos[i, 2]),
                "t_from_launch_s": float(run.t_s[i]),
                "beacons_visible": float(sum(bool(v[i]) for v in run.visible.values())),
            },
        )

    def events(self) -> Iterator[Event]:
        duration = self.context.duration_ns
        stamps = self.run.stamps_ns
        index = {int(s): i for i, s in enumerate(stamps.tolist())}
        truth_done: set[int] = set()
        drops = [
            (_DROPOUT_TYPES[d.stream], round(d.start_s * NS_PER_S), round((d.start_s + d.duration_s) * NS_PER_S))
            for d in self.params.dropouts
        ]
        for msg in self.run.messages:
            stamp = msg.header.stamp_ns
            if stamp > duration:
                return
            if any(isinstance(msg, cls) and a <= stamp < b for cls, a, b in drops):
                continue
            if self.params.publish_truth and stamp not in truth_done and not isinstance(msg, BeaconTable | Current):
                truth_done.add(stamp)
                yield Event(stamp, self.truth_key, self._truth(index[stamp], stamp))
            yield Event(stamp, self.keys[type(msg).__name__], msg)


def sim_params(scenario: Any, vehicle: str | None = None) -> LblSimParams:
    """The ``lbl_nav`` simulator parameters of ``vehicle`` (None: the scenario's only ``lbl_nav`` simulator)."""
    found: list[LblSimParams] = []
    for i, spec in enumerate(scenario.simulators):
        if spec.kind == "lbl_nav":
            p = scenario.simulator_params(i)
            assert isinstance(p, LblSimParams)
            if vehicle is None or p.platform == vehicle:
                found.append(p)
    if len(found) != 1:
        who = "" if vehicle is None else f" for vehicle {vehicle!r}"
        raise ValueError(f"scenario {scenario.name}: {len(found)} lbl_nav simulators{who}; expected one")
    return found[0]


__all__ = [
    "CURRENT",
    "DEPTH",
    "HEADING",
    "LOG",
    "RANGES",
    "SENSOR_TYPES",
    "TABLE",
    "BeaconParams",
    "DropoutParams",
    "LblNavSimulator",
    "LblSimParams",
    "SimTruth",
    "TrackTruth",
    "recorded_path",
    "sensor_keys",
    "sim_params",
]
