"""Player plugin ``attitude``: one monostatic 3-D radar site and the aircraft it sees (digest 004 §3.1, §5.1).

Wraps the core's pure simulation (:mod:`services.attitude.simulation`): coordinated flight along a
:class:`~services.attitude.simulation.FlightPlan` (the paper's §3.1 straight-and-level scenario, the three
manoeuvring plans, or a start state plus turn/climb/acceleration segments given in the file), and plots =
true (range, azimuth, elevation) + independent Gaussian noise with the radar's sigmas (§4.6). Keys
(``<site>`` = ``site_id``, ``<sensor>`` = ``sensor_id``, default ``plots``):

* ``fixstream/sensor/<site>/radar/<sensor>``: every :class:`~schemas.RadarPlot` in stamp order;
  ``.../<sensor>/site``: one :class:`~schemas.RadarSite` at t = 0 (the site's sigmas and scan period, unless
  ``publish_site: false``); ``.../<sensor>/track_end``: a :class:`~schemas.TrackEnd` after a target's last plot
  when it has ``track_end: true``. One key per message type; the service subscribes to ``.../<sensor>/**``
  with one subscriber, so it sees one publisher's messages in the order they were made;
* ``fixstream/truth/<target id>``: :class:`~schemas.Truth` at every scan time of the target (also when its
  plot is missing), unless ``publish_truth: false``: position, velocity and acceleration ``[east, north, up]``
  in the scenario frame (the radar at ``site_position_m``), ``attitude_rad`` = [heading, pitch, roll] of the
  coordinated flight, and ``extra``: true ``range_m``, ``az_deg``, ``el_deg`` seen from the radar and
  ``speed_mps``.

A target with ``track`` (:class:`~services.player.simulators.recorded_track.TrackFileParams`) flies a recorded
trajectory file instead (docs/scenarios.md, "Trajectory files"; an ADS-B log, say): its local frame must be the
radar's (``track.origin`` at the radar for a geodetic file; the radar sits at ``site_position_m`` of that frame),
and its plots end with the track (``end_s`` is capped at the track's last row). The truth angles are those of
the estimator's convention (:func:`~services.attitude.simulation.coordinated_roll`, heading and flight-path
angle of the velocity), from the track's smoothed velocity and acceleration, or the recorded heading, pitch and
roll when the file has them; ``phases`` of a track come from its smoothed motion (turn: roll above
TURN_ROLL_DEG; manoeuvre: acceleration above TRACK_MANOEUVRE_ACCEL_MPS2).

Every target's trajectory is registered in the scenario context under its id (ENU, for later simulators).
Randomness: target ``<id>``'s plot noise comes from the child stream ``noise/<id>``, its detection draws from
``detect/<id>`` and the generated targets (``random_targets``) from ``random_targets``, so adding a target
does not change the others' noise.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterator
from dataclasses import dataclass, replace
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, Field, model_validator

from schemas import RadarPlot, RadarSite, TrackEnd, Truth
from services.player.simulators import (
    NS_PER_S,
    Event,
    ScenarioContext,
    SimParams,
    TruthState,
    child_rng,
    register,
)
from services.player.simulators.recorded_track import RecordedTrack, TrackFileParams, load_cached
from shared import keys

from .config import RADAR_PRESETS, MeasurementSigmas, RadarPreset
from .simulation import (
    FlightPlan,
    Segment,
    TruthStates,
    Wander,
    coordinated_roll,
    fly,
    manoeuvring_plans,
    measure,
    paper_plan,
    true_spherical,
)
from .topics import radar_key, site_key, track_end_key

KeyChunk = Annotated[str, AfterValidator(keys.chunk)]
Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Rate = float | Annotated[list[float], Field(min_length=2, max_length=2)]

#: the named flight plans of the core's simulation: "paper" (§3.1) and the manoeuvring ones
NAMED_PLANS = ("paper", "turn30", "climb10", "weave")
#: plot order within one stamp: the site first, then per target (file order): truth, plot, track end
_SITE, _TRUTH, _PLOT, _END = 0, 1, 2, 3


def enu_to_nue(v: np.ndarray) -> np.ndarray:
    """[east, north, up] -> the radar frame E of the digest [north, up, east] (last axis)."""
    return np.asarray(v)[..., [1, 2, 0]]


def nue_to_enu(v: np.ndarray) -> np.ndarray:
    """The radar frame E [north, up, east] -> [east, north, up] (last axis)."""
    return np.asarray(v)[..., [2, 0, 1]]


class StartParams(SimParams):
    """Initial state: a position (``position_m``, or ``range_m`` + ``azimuth_deg`` + ``altitude_m``) and velocity."""

    position_m: Vec3 | None = Field(default=None, description="[east, north, up] relative to the radar, m")
    range_m: float | None = Field(default=None, gt=0.0, le=2.0e6, description="slant range from the radar, m")
    azimuth_deg: float | None = Field(default=None, ge=-360.0, le=360.0, description="clockwise from north, deg")
    altitude_m: float | None = Field(default=None, ge=-1000.0, le=30_000.0, description="height above the radar, m")
    heading_deg: float = Field(ge=-360.0, le=360.0, description="flight-path heading, clockwise from north, deg")
    pitch_deg: float = Field(default=0.0, ge=-80.0, le=80.0, description="flight-path angle, nose up +, deg")
    speed_mps: float = Field(gt=0.0, le=1500.0, description="speed along the flight path, m/s")

    @model_validator(mode="after")
    def _one_position(self) -> StartParams:
        polar = [v is not None for v in (self.range_m, self.azimuth_deg, self.altitude_m)]
        if (self.position_m is not None and any(polar)) or (self.position_m is None and not all(polar)):
            raise ValueError("give position_m, or all of range_m, azimuth_deg and altitude_m")
        if self.range_m is not None and self.altitude_m is not None and abs(self.altitude_m) >= self.range_m:
            raise ValueError("altitude_m must be smaller than range_m")
        return self

    def position_nue(self) -> tuple[float, float, float]:
        """Start position in the radar frame E [north, up, east], m."""
        if self.position_m is not None:
            e, n, u = self.position_m
            return (n, u, e)
        assert self.range_m is not None and self.azimuth_deg is not None and self.altitude_m is not None
        p = paper_plan(r0_m=self.range_m, az0_deg=self.azimuth_deg, h0_m=self.altitude_m).p0_m
        return (p[0], p[1], p[2])


class SegmentParams(SimParams):
    """One manoeuvre segment; a rate, bank or load factor is a constant or ``[from, to]``, ramped linearly over the
    segment. ``bank_deg`` and ``load_factor`` fly the coordinated-flight equations (``simulation.Segment``)."""

    duration_s: float = Field(gt=0.0, le=1e6, description="s")
    turn_rate_dps: Rate = Field(default=0.0, description="d(heading)/dt, deg/s, + to starboard (clockwise)")
    bank_deg: Rate | None = Field(
        default=None,
        description="coordinated turn at this bank, deg (+ right wing down): turn rate n g sin(bank) / (V cos(pitch)), "
        "with n = cos(pitch) / cos(bank) unless load_factor is given (a level turn: g tan(bank) / V)",
    )
    load_factor: Rate | None = Field(
        default=None,
        description="normal load factor n (lift / weight; 1 = level flight, 2 = a 2 g pull-up, 0 = a zero-g parabola): "
        "d(pitch)/dt = (n g cos(bank) - g cos(pitch)) / V",
    )
    gravity_speed: bool = Field(default=False, description="the speed also changes by -g sin(pitch) (unpowered arc)")
    pitch_rate_dps: Rate = Field(default=0.0, description="d(flight-path angle)/dt, deg/s, + nose up")
    accel_mps2: float = Field(default=0.0, ge=-50.0, le=50.0, description="dV/dt along the path, m/s^2")

    @model_validator(mode="after")
    def _rates(self) -> SegmentParams:
        for name in ("turn_rate_dps", "pitch_rate_dps"):
            for r in _pair(getattr(self, name)):
                if abs(r) > 30.0:
                    raise ValueError(f"{name}: |rate| must be at most 30 deg/s, got {r}")
        if self.bank_deg is not None:
            if any(abs(b) >= 80.0 for b in _pair(self.bank_deg)):
                raise ValueError("bank_deg: |bank| must be below 80 deg")
            if self.turn_rate_dps != 0.0:
                raise ValueError("bank_deg sets the turn rate: no turn_rate_dps with it")
        if self.load_factor is not None and any(not -3.0 <= n <= 9.0 for n in _pair(self.load_factor)):
            raise ValueError("load_factor: n must be within [-3, 9]")
        return self

    def coordinated(self) -> bool:
        """True if the coordinated-flight equations drive this segment (bank or load factor given)."""
        return self.bank_deg is not None or self.load_factor is not None


class WanderParams(SimParams):
    """Small random manoeuvres (light turbulence, pilot corrections): Ornstein-Uhlenbeck accelerations across,
    normal to and along the path (``simulation.Wander``); a new realisation every run (stream ``wander/<id>``)."""

    sigma_lat_mps2: float = Field(default=0.2, ge=0.0, le=5.0, description="across the path, horizontal, m/s^2")
    sigma_vert_mps2: float = Field(default=0.2, ge=0.0, le=5.0, description="normal to the path, vertical, m/s^2")
    sigma_long_mps2: float = Field(default=0.05, ge=0.0, le=5.0, description="along the path, m/s^2")
    tau_s: float = Field(default=20.0, gt=0.0, le=3600.0, description="correlation time, s")


def _pair(rate: float | list[float]) -> tuple[float, float]:
    if isinstance(rate, list):
        return (float(rate[0]), float(rate[1]))
    return (float(rate), float(rate))


class TargetParams(SimParams):
    """One aircraft: a named plan, a start state and segments (after the last one it flies straight), or a
    recorded track."""

    id: KeyChunk = Field(description="target id: RadarPlot.target_id and the truth key fixstream/truth/<id>")
    plan: Literal["paper", "turn30", "climb10", "weave"] | None = Field(
        default=None, description="a named plan: paper (§3.1: 100 km, 60 deg, 5 km, 220 deg, 200 m/s) or manoeuvring"
    )
    start: StartParams | None = Field(default=None, description="initial state (instead of plan)")
    track: TrackFileParams | None = Field(
        default=None, description="a recorded trajectory (instead of plan or start); local frame = the radar's"
    )
    segments: list[SegmentParams] = Field(default_factory=list, max_length=1000)
    phase_s: float = Field(default=0.0, ge=0.0, description="time of the target's first plot, s")
    end_s: float | None = Field(default=None, gt=0.0, description="no plots after this time, s (None: to the end)")
    missed_scans: list[Annotated[int, Field(ge=1)]] = Field(
        default_factory=list, max_length=100_000, description="scan numbers (1 = first) without a plot"
    )
    p_detect: float = Field(default=1.0, gt=0.0, le=1.0, description="probability that a scan gives a plot")
    track_end: bool = Field(default=False, description="publish a TrackEnd right after the last plot")
    wander: WanderParams | None = Field(
        default=None, description="small random manoeuvres on top of the plan, a new realisation every run"
    )

    @model_validator(mode="after")
    def _one_plan(self) -> TargetParams:
        if sum(x is not None for x in (self.plan, self.start, self.track)) != 1:
            raise ValueError("give exactly one of plan and start (or a track instead of either)")
        if self.track is not None:
            if self.segments or self.wander is not None:
                raise ValueError("a recorded track is the whole motion: no segments or wander with it")
            if self.phase_s < self.track.time_offset_s:
                raise ValueError("phase_s: the first plot cannot be before the track's first row (time_offset_s)")
            load_cached(self.track)  # a missing or malformed file is a parameter error
        if self.plan is not None and self.segments:
            raise ValueError("segments go with start, not with a named plan")
        if self.end_s is not None and self.end_s < self.phase_s:
            raise ValueError("end_s must not be before phase_s")
        if self.start is not None:
            speed, pitch = self.start.speed_mps, self.start.pitch_deg
            for i, seg in enumerate(self.segments):
                if seg.coordinated() or seg.gravity_speed:
                    break  # the path then follows the equations of motion: checked when it is flown
                speed += seg.accel_mps2 * seg.duration_s
                p0, p1 = _pair(seg.pitch_rate_dps)
                pitch += 0.5 * (p0 + p1) * seg.duration_s
                if speed < 1.0:
                    raise ValueError(f"segments[{i}]: the speed falls to {speed:.1f} m/s (must stay >= 1 m/s)")
                if abs(pitch) > 80.0:
                    raise ValueError(f"segments[{i}]: the flight-path angle reaches {pitch:.1f} deg (limit 80)")
        return self

    def flight_plan(self) -> FlightPlan:
        if self.plan == "paper":
            return paper_plan()
        if self.plan is not None:
            return manoeuvring_plans()[self.plan]
        assert self.start is not None
        st = self.start
        segs = [
            Segment(
                seg.duration_s,
                _pair(seg.turn_rate_dps),
                _pair(seg.pitch_rate_dps),
                seg.accel_mps2,
                bank_deg=None if seg.bank_deg is None else _pair(seg.bank_deg),
                load_factor=None if seg.load_factor is None else _pair(seg.load_factor),
                gravity_speed=seg.gravity_speed,
            )
            for seg in self.segments
        ]
        return FlightPlan(
            p0_m=st.position_nue(),
            speed_mps=st.speed_mps,
            psi_deg=st.heading_deg,
            theta_deg=st.pitch_deg,
            segments=tuple(segs),
        )


class RandomTargets(SimParams):
    """Many straight-flying targets with random starts (for load tests), ids ``<prefix>0``, ``<prefix>1``, ..."""

    count: int = Field(ge=1, le=100_000)
    prefix: KeyChunk = Field(default="t", description="id prefix")
    range_m: Annotated[list[float], Field(min_length=2, max_length=2)] = Field(
        default_factory=lambda: [40e3, 150e3], description="[low, high] of the uniform start range, m"
    )
    altitude_m: Annotated[list[float], Field(min_length=2, max_length=2)] = Field(
        default_factory=lambda: [1e3, 10e3], description="[low, high] of the uniform start altitude, m"
    )
    speed_mps: Annotated[list[float], Field(min_length=2, max_length=2)] = Field(
        default_factory=lambda: [120.0, 280.0], description="[low, high] of the uniform speed, m/s"
    )
    spread_phase: bool = Field(
        default=True, description="first plot of each target at a uniform random time within the first scan"
    )

    @model_validator(mode="after")
    def _intervals(self) -> RandomTargets:
        for name in ("range_m", "altitude_m", "speed_mps"):
            lo, hi = getattr(self, name)
            if not 0.0 < lo <= hi:
                raise ValueError(f"{name}: expected 0 < low <= high, got {[lo, hi]}")
        if self.altitude_m[1] >= self.range_m[0]:
            raise ValueError("altitude_m must stay below range_m")
        return self


class AttitudeSimParams(SimParams):
    """Parameters of ``attitude``: the radar site, its sigmas and scan period, and its targets."""

    site_id: KeyChunk = Field(description="radar site id: keys fixstream/sensor/<site_id>/radar/<sensor_id>")
    sensor_id: KeyChunk = Field(default="plots", description="last chunk of the plot key")
    radar: RadarPreset | None = Field(
        default="9S15", description="sigma preset of the digest's §3.2 (9S15, Vostok3D, 19Zh6); sigma_* override it"
    )
    sigma_r_m: float | None = Field(default=None, gt=0.0, le=10_000.0, description="range error std, m")
    sigma_az_deg: float | None = Field(default=None, gt=0.0, le=10.0, description="azimuth error std, deg")
    sigma_el_deg: float | None = Field(default=None, gt=0.0, le=10.0, description="elevation error std, deg")
    scan_period_s: float = Field(default=5.0, gt=0.0, le=3600.0, description="scan period T, s")
    site_position_m: Vec3 = Field(
        default_factory=lambda: [0.0, 0.0, 0.0], description="radar position [east, north, up] in the scenario frame"
    )
    lat_deg: float = Field(default=0.0, ge=-90.0, le=90.0, description="site latitude in RadarSite, deg")
    lon_deg: float = Field(default=0.0, ge=-180.0, le=180.0, description="site longitude in RadarSite, deg")
    publish_site: bool = Field(default=True, description="publish a RadarSite (sigmas, scan period) at t = 0")
    publish_truth: bool = Field(default=True, description="publish Truth of every target on fixstream/truth/<id>")
    targets: list[TargetParams] = Field(default_factory=list, max_length=100_000)
    random_targets: RandomTargets | None = Field(default=None, description="add generated straight targets")

    @model_validator(mode="after")
    def _check(self) -> AttitudeSimParams:
        if self.radar is None and None in (self.sigma_r_m, self.sigma_az_deg, self.sigma_el_deg):
            raise ValueError("give a radar preset or all three sigma_* values")
        ids = [t.id for t in self.targets]
        for i, tid in enumerate(ids):
            if tid in ids[:i]:
                raise ValueError(f"targets[{i}].id: duplicate target id {tid!r}")
        if not self.targets and self.random_targets is None:
            raise ValueError("give targets or random_targets")
        return self

    def sigmas(self) -> MeasurementSigmas:
        base = RADAR_PRESETS[self.radar] if self.radar is not None else (math.nan, math.nan, math.nan)
        return MeasurementSigmas(
            sigma_r_m=self.sigma_r_m if self.sigma_r_m is not None else base[0],
            sigma_az_deg=self.sigma_az_deg if self.sigma_az_deg is not None else base[1],
            sigma_el_deg=self.sigma_el_deg if self.sigma_el_deg is not None else base[2],
        )


#: a commanded acceleration above this (m/s^2) is a manoeuvre; a commanded roll above TURN_ROLL_DEG is a turn
MANOEUVRE_ACCEL_MPS2 = 1e-3
TURN_ROLL_DEG = 5.0
#: a recorded track commands nothing: its smoothed acceleration above this (m/s^2, 0.1 g) is a manoeuvre (the
#: GCV spline of a 1 Hz ADS-B-like track with 3 m noise wobbles by up to 1 m/s^2 on straight legs)
TRACK_MANOEUVRE_ACCEL_MPS2 = 0.1 * 9.81


class TargetTruth:
    """Exact truth of one target in the scenario frame (a :class:`~services.player.simulators.TruthSource`)."""

    def __init__(self, plan: FlightPlan, site_enu_m: list[float]) -> None:
        self.plan = plan
        self.site = np.asarray(site_enu_m, dtype=np.float64)

    def states(self, stamps_ns: np.ndarray) -> TruthStates:
        """The core's truth (radar frame E) at the stamps."""
        return fly(self.plan, np.asarray(stamps_ns, dtype=np.float64) / NS_PER_S)

    def phases(self, stamps_ns: np.ndarray) -> dict[str, np.ndarray]:
        """What the plan commands at the stamps (the plan without its wander): ``manoeuvre`` (1.0 while a segment
        commands an acceleration), ``turn`` (1.0 while the commanded roll exceeds TURN_ROLL_DEG) and
        ``since_manoeuvre_s`` (time since a commanded manoeuvre last ended; the stamp's time if there was none)."""
        t = np.asarray(stamps_ns, dtype=np.float64) / NS_PER_S
        if not self.plan.segments:
            zero = np.zeros(t.size)
            return {"manoeuvre": zero, "turn": zero, "since_manoeuvre_s": t.copy()}
        base = fly(replace(self.plan, wander=None), t)
        man = np.linalg.norm(base.a, axis=1) > MANOEUVRE_ACCEL_MPS2
        turn = np.abs(np.degrees(base.gamma)) > TURN_ROLL_DEG
        since = np.empty(t.size)
        last_end = 0.0
        for k in range(t.size):
            if man[k]:
                last_end = t[k]
            since[k] = t[k] - last_end
        return {"manoeuvre": man.astype(np.float64), "turn": turn.astype(np.float64), "since_manoeuvre_s": since}

    def truth_at(self, stamps_ns: np.ndarray) -> TruthState:
        st = self.states(stamps_ns)
        return TruthState(
            position_m=self.site + nue_to_enu(st.p),
            velocity_mps=nue_to_enu(st.v),
            heading_rad=np.mod(st.psi, 2 * math.pi),
            pitch_rad=st.theta,
            roll_rad=st.gamma,
        )


class TrackTargetTruth:
    """Truth of a target flying a recorded track (the interface of :class:`TargetTruth`), radar frame E."""

    def __init__(self, track: RecordedTrack, site_enu_m: list[float]) -> None:
        self.track = track
        self.site = np.asarray(site_enu_m, dtype=np.float64)

    def states(self, stamps_ns: np.ndarray) -> TruthStates:
        """The track at the stamps in frame E: position from the radar, velocity, acceleration; heading and
        flight-path angle of the velocity (or recorded); roll of coordinated flight (or recorded)."""
        t = np.asarray(stamps_ns, dtype=np.float64) / NS_PER_S
        st = self.track.states(t)
        p, v, a = enu_to_nue(st.position_m - self.site), enu_to_nue(st.velocity_mps), enu_to_nue(st.acceleration_mps2)
        gamma = st.roll_rad if self.track.has_attitude else coordinated_roll(v, a)
        return TruthStates(t, p, v, a, np.mod(st.heading_rad, 2 * math.pi), st.pitch_rad, gamma)

    def phases(self, stamps_ns: np.ndarray) -> dict[str, np.ndarray]:
        """As :meth:`TargetTruth.phases`, from the smoothed motion (see the module docstring)."""
        st = self.states(stamps_ns)
        man = np.linalg.norm(st.a, axis=1) > TRACK_MANOEUVRE_ACCEL_MPS2
        turn = np.abs(np.degrees(st.gamma)) > TURN_ROLL_DEG
        man |= turn
        since = np.empty(st.t_s.size)
        last_end = self.track.start_s
        for k in range(st.t_s.size):
            if man[k]:
                last_end = st.t_s[k]
            since[k] = st.t_s[k] - last_end
        return {"manoeuvre": man.astype(np.float64), "turn": turn.astype(np.float64), "since_manoeuvre_s": since}

    def truth_at(self, stamps_ns: np.ndarray) -> TruthState:
        st = self.states(stamps_ns)
        return TruthState(self.site + nue_to_enu(st.p), nue_to_enu(st.v), st.psi, st.theta, st.gamma)


@dataclass(frozen=True)
class _Target:
    """A target's plan (or recorded track) and schedule, resolved from :class:`TargetParams` or drawn by
    :class:`RandomTargets`."""

    id: str
    plan: FlightPlan | None
    phase_s: float
    end_s: float | None = None
    missed: frozenset[int] = frozenset()
    p_detect: float = 1.0
    track_end: bool = False
    track: RecordedTrack | None = None


@register("attitude")
class AttitudeRadar:
    """Plots, site description and truth of one radar site; see the module docstring."""

    Params = AttitudeSimParams

    def __init__(self, params: AttitudeSimParams, rng: np.random.Generator, context: ScenarioContext) -> None:
        self.params = params
        self.rng = rng
        self.context = context
        self.key = radar_key(params.site_id, params.sensor_id)
        self.site_key = site_key(params.site_id, params.sensor_id)
        self.end_key = track_end_key(params.site_id, params.sensor_id)
        self.sigmas = params.sigmas()
        self.targets = [self._target(t) for t in params.targets]
        if params.random_targets is not None:
            self.targets.extend(self._random_targets(params.random_targets, child_rng(rng, "random_targets")))
        ids = [t.id for t in self.targets]
        if len(set(ids)) != len(ids):
            raise ValueError("a generated target id equals a listed one; change random_targets.prefix")
        self.truths = {t.id: self._truth_source(t) for t in self.targets}
        for tid, source in self.truths.items():
            context.register_platform(tid, source)

    def _target(self, t: TargetParams) -> _Target:
        missed = frozenset(t.missed_scans)
        if t.track is None:
            return _Target(t.id, self._wandering(t), t.phase_s, t.end_s, missed, t.p_detect, t.track_end)
        track = load_cached(t.track)
        end = track.end_s if t.end_s is None else min(t.end_s, track.end_s)
        return _Target(t.id, None, t.phase_s, end, missed, t.p_detect, t.track_end, track)

    def _truth_source(self, t: _Target) -> TargetTruth | TrackTargetTruth:
        if t.track is not None:
            return TrackTargetTruth(t.track, self.params.site_position_m)
        assert t.plan is not None
        return TargetTruth(t.plan, self.params.site_position_m)

    def _wandering(self, target: TargetParams) -> FlightPlan:
        """The target's plan with its wander, a realisation drawn from the stream ``wander/<id>`` of this run."""
        plan = target.flight_plan()
        w = target.wander
        if w is None:
            return plan
        seed = int(child_rng(self.rng, f"wander/{target.id}").integers(0, 2**63 - 1))
        wander = Wander(w.sigma_lat_mps2, w.sigma_vert_mps2, w.sigma_long_mps2, w.tau_s, seed)
        return replace(plan, wander=wander)

    def _random_targets(self, spec: RandomTargets, rng: np.random.Generator) -> list[_Target]:
        out = []
        for i in range(spec.count):
            r0 = rng.uniform(spec.range_m[0], spec.range_m[1])
            h0 = rng.uniform(spec.altitude_m[0], spec.altitude_m[1])
            az0 = rng.uniform(0.0, 360.0)
            psi = rng.uniform(0.0, 360.0)
            v = rng.uniform(spec.speed_mps[0], spec.speed_mps[1])
            phase = rng.uniform(0.0, self.params.scan_period_s) if spec.spread_phase else 0.0
            plan = paper_plan(
                r0_m=float(r0), az0_deg=float(az0), h0_m=float(h0), psi_deg=float(psi), speed_mps=float(v)
            )
            out.append(_Target(f"{spec.prefix}{i}", plan, float(phase)))
        return out

    def _scan_stamps(self, target: _Target) -> np.ndarray:
        """Stamps (ns) of the target's scans: phase + k T inside [phase, min(end, duration)]."""
        t_end = self.context.duration_s if target.end_s is None else min(target.end_s, self.context.duration_s)
        period = self.params.scan_period_s
        if target.phase_s > t_end:
            return np.zeros(0, dtype=np.int64)
        n = math.floor((t_end - target.phase_s) / period + 1e-9) + 1
        stamps = np.array([round((target.phase_s + k * period) * NS_PER_S) for k in range(n)], dtype=np.int64)
        return stamps[stamps <= self.context.duration_ns]

    def _site_event(self) -> Event:
        p = self.params
        msg = RadarSite(
            header=self.context.header(0),
            site_id=p.site_id,
            lat_deg=p.lat_deg,
            lon_deg=p.lon_deg,
            h_m=min(max(p.site_position_m[2], -500.0), 10_000.0),
            sigma_r_m=self.sigmas.sigma_r_m,
            sigma_az_deg=self.sigmas.sigma_az_deg,
            sigma_el_deg=self.sigmas.sigma_el_deg,
            scan_period_s=p.scan_period_s,
        )
        return Event(0, self.site_key, msg)

    def _target_events(self, index: int, target: _Target) -> Iterator[tuple[int, int, int, int, Event]]:
        """(stamp, target index, kind, k, event) of one target, in stamp order."""
        p = self.params
        stamps = self._scan_stamps(target)
        if stamps.size == 0:
            return
        truth = self.truths[target.id].states(stamps)
        meas = measure(truth, self.sigmas, child_rng(self.rng, f"noise/{target.id}"))[0].tolist()
        detected = np.ones(stamps.size, dtype=bool)
        if target.p_detect < 1.0:
            detected = child_rng(self.rng, f"detect/{target.id}").random(stamps.size) < target.p_detect
        for k in target.missed:
            if k <= stamps.size:
                detected[k - 1] = False
        r, beta, eps = true_spherical(truth.p)
        site = np.asarray(p.site_position_m)
        pos, vel, acc = site + nue_to_enu(truth.p), nue_to_enu(truth.v), nue_to_enu(truth.a)
        truth_key = keys.truth(target.id)
        phases = self.truths[target.id].phases(stamps) if p.publish_truth else {}
        last_plot = int(np.flatnonzero(detected)[-1]) if detected.any() else -1
        for k, stamp in enumerate(stamps.tolist()):
            header = self.context.header(stamp)
            if p.publish_truth:
                msg = Truth(
                    header=header,
                    platform=target.id,
                    position_m=pos[k].tolist(),
                    velocity_mps=vel[k].tolist(),
                    acceleration_mps2=acc[k].tolist(),
                    attitude_rad=[float(truth.psi[k]), float(truth.theta[k]), float(truth.gamma[k])],
                    extra={
                        "range_m": float(r[k]),
                        "az_deg": math.degrees(float(beta[k])),
                        "el_deg": math.degrees(float(eps[k])),
                        "speed_mps": float(np.linalg.norm(truth.v[k])),
                        **{name: float(v[k]) for name, v in phases.items()},
                    },
                )
                yield (stamp, index, _TRUTH, k, Event(stamp, truth_key, msg))
            if detected[k]:
                rng_m, az, el = meas[k]
                plot = RadarPlot(
                    header=header, site_id=p.site_id, target_id=target.id, range_m=rng_m, az_deg=az, el_deg=el
                )
                yield (stamp, index, _PLOT, k, Event(stamp, self.key, plot))
            if target.track_end and k == last_plot:
                end = TrackEnd(header=header, site_id=p.site_id, target_id=target.id)
                yield (stamp, index, _END, k, Event(stamp, self.end_key, end))

    def events(self) -> Iterator[Event]:
        streams = [self._target_events(i, t) for i, t in enumerate(self.targets)]
        if self.params.publish_site:
            yield self._site_event()
        for item in heapq.merge(*streams, key=lambda e: (e[0], e[1], e[2])):
            yield item[4]


__all__ = [
    "NAMED_PLANS",
    "AttitudeRadar",
    "AttitudeSimParams",
    "RandomTargets",
    "SegmentParams",
    "StartParams",
    "TargetParams",
    "TargetTruth",
    "TrackTargetTruth",
    "WanderParams",
    "enu_to_nue",
    "nue_to_enu",
    "radar_key",
    "site_key",
    "track_end_key",
]
