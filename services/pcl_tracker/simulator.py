"""Player plugin ``pcl_tracker``: one receiver–illuminator pair of a passive coherent locator and its targets.

Wraps the core's pure simulation (:func:`services.pcl_tracker.simulation.simulate`): transmitter and receiver
geometry, any number of targets on straight or turning paths, detection probability, Poisson clutter in the
bistatic measurement box and the paper's Gaussian noise on (r_b, azimuth, elevation, v_b) (digest 003 §3.1,
§4.4). Every scan time ``start_s + k * scan_period_s`` inside the scenario yields

* ``fixstream/truth/<target id>``: :class:`~schemas.truth.Truth` of every target alive then (position and
  velocity, ENU at the receiver), unless ``publish_truth: false`` (a second pair seeing the same targets);
* ``fixstream/sensor/<receiver_id>/pcl/<illuminator_id>``: one :class:`~schemas.radar.BistaticScan` with
  ``scan_id`` = k + 1 (empty scans too).

A target with ``track`` (:class:`~services.player.simulators.recorded_track.TrackFileParams`) flies a recorded
trajectory file instead of the straight/turning motion (docs/scenarios.md, "Trajectory files"): its local frame
must be the receiver's (``track.origin`` at the receiver for a geodetic file); it is born at the track's first
row and ends (no truth, no plots) after its last one.

Frame: ENU with the receiver at the origin (the scenario's ``frame_id``); azimuth clockwise from north.
All randomness comes from the simulator's own generator, in the core simulation's order.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, Field, model_validator

from services.player.simulators import NS_PER_S, Event, ScenarioContext, SimParams, TruthState, register
from services.player.simulators.recorded_track import RecordedTrack, TrackFileParams, load_cached
from shared import keys

from .service import input_key
from .simulation import (
    PAPER_SIGMA,
    PAPER_TX_M,
    ClutterSpec,
    PclScenario,
    SnrSpec,
    TargetSpec,
    many_target_scenario,
    simulate,
)

G_MPS2 = 9.80665

KeyChunk = Annotated[str, AfterValidator(keys.chunk)]
Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Interval = Annotated[list[float], Field(min_length=2, max_length=2)]


def _increasing(name: str, v: list[float]) -> None:
    if not v[0] < v[1]:
        raise ValueError(f"{name}: expected [low, high] with low < high, got {v}")


#: the fields of a target's synthetic motion, which a recorded track replaces
MOTION_FIELDS = (
    "position_m",
    "velocity_mps",
    "speed_mps",
    "course_deg",
    "climb_rate_mps",
    "birth_s",
    "death_s",
    "turn_rate_dps",
    "turn_start_s",
    "turn_end_s",
)


class TargetParams(SimParams):
    """One target: straight flight, optionally with one horizontal coordinated turn, or a recorded track."""

    id: KeyChunk = Field(description="platform id: truth on fixstream/truth/<id>")
    position_m: Vec3 | None = Field(
        default=None, description="[east, north, up] at birth_s, relative to the receiver, m (unless track)"
    )
    velocity_mps: Vec3 | None = Field(default=None, description="[east, north, up] velocity, m/s (or speed/course)")
    speed_mps: float | None = Field(default=None, ge=0.0, le=3000.0, description="horizontal speed, m/s")
    course_deg: float = Field(default=0.0, ge=-360.0, le=360.0, description="course, deg clockwise from north")
    climb_rate_mps: float = Field(default=0.0, ge=-500.0, le=500.0, description="vertical speed, m/s (+ up)")
    birth_s: float = Field(default=0.0, ge=0.0, description="first time the target exists, s")
    death_s: float | None = Field(default=None, gt=0.0, description="last time it exists, s (None: never dies)")
    turn_rate_dps: float = Field(default=0.0, ge=-30.0, le=30.0, description="deg/s, + clockwise from above")
    turn_start_s: float = Field(default=0.0, ge=0.0, description="s")
    turn_end_s: float | None = Field(default=None, gt=0.0, description="s (None: turns until death)")
    track: TrackFileParams | None = Field(
        default=None, description="a recorded trajectory instead (local frame: the receiver's); born and ends with it"
    )

    @model_validator(mode="after")
    def _check(self) -> TargetParams:
        if self.track is not None:
            given = [f for f in MOTION_FIELDS if f in self.model_fields_set]
            if given:
                raise ValueError(f"track replaces the target's motion: remove {', '.join(given)}")
            load_cached(self.track)  # a missing or malformed file is a parameter error
            return self
        if self.position_m is None:
            raise ValueError("give position_m (with velocity_mps or speed_mps) or a track")
        if (self.velocity_mps is None) == (self.speed_mps is None):
            raise ValueError("give exactly one of velocity_mps and speed_mps (with course_deg, climb_rate_mps)")
        if self.death_s is not None and self.death_s <= self.birth_s:
            raise ValueError("death_s must be after birth_s")
        if self.turn_end_s is not None and self.turn_end_s <= self.turn_start_s:
            raise ValueError("turn_end_s must be after turn_start_s")
        return self

    def spec(self) -> TargetSpec:
        if self.track is not None:
            return TrackTargetSpec.of(self.id, load_cached(self.track))
        assert self.position_m is not None
        if self.velocity_mps is not None:
            v = tuple(self.velocity_mps)
        else:
            c = math.radians(self.course_deg)
            speed = float(self.speed_mps or 0.0)
            v = (speed * math.sin(c), speed * math.cos(c), self.climb_rate_mps)
        return TargetSpec(
            self.id,
            (self.position_m[0], self.position_m[1], self.position_m[2]),
            (v[0], v[1], v[2]),
            t_birth_s=self.birth_s,
            t_death_s=math.inf if self.death_s is None else self.death_s,
            turn_rate_dps=self.turn_rate_dps,
            turn_start_s=self.turn_start_s,
            turn_end_s=math.inf if self.turn_end_s is None else self.turn_end_s,
        )


@dataclass(frozen=True)
class TrackTargetSpec(TargetSpec):
    """A target flying a recorded track: :meth:`state` is the track's (smoothed) position and velocity between
    its first and last rows (``t_birth_s``, ``t_death_s``), None outside."""

    track: RecordedTrack | None = None

    @classmethod
    def of(cls, target_id: str, track: RecordedTrack) -> TrackTargetSpec:
        st = track.states(np.array([track.start_s]))
        p, v = st.position_m[0], st.velocity_mps[0]
        return cls(
            target_id,
            (float(p[0]), float(p[1]), float(p[2])),
            (float(v[0]), float(v[1]), float(v[2])),
            t_birth_s=track.start_s,
            t_death_s=track.end_s,
            track=track,
        )

    def state(self, t: float) -> np.ndarray | None:
        if t < self.t_birth_s or t > self.t_death_s or self.track is None:
            return None
        st = self.track.states(np.array([t]))
        out: np.ndarray = np.concatenate([st.position_m[0], st.velocity_mps[0]])
        return out


class RandomTargetsParams(SimParams):
    """Many targets laid out by their own seed (same layout in every run), as the core's many-target case:
    15–60 km from the receiver, 500–8000 m up, 120–280 m/s on random courses, half of them turning at
    0.3–0.8 deg/s between t = 40 and 80 s. Ids ``<id_prefix>1`` ... ``<id_prefix><count>``."""

    count: int = Field(ge=1, le=10_000, description="number of targets")
    layout_seed: int = Field(default=7, ge=0, lt=2**32, description="seed of the layout (not of the noise)")
    id_prefix: KeyChunk = Field(default="target", description="platform id prefix")


class ClutterParams(SimParams):
    """Poisson clutter, uniform in the bistatic measurement box (digest §4.4 E5 defaults)."""

    rate_per_scan: float = Field(default=0.0, ge=0.0, le=1e6, description="mean false plots per scan")
    rb_range_m: Interval = Field(default_factory=lambda: [0.0, 50_000.0], description="bistatic range, m")
    az_range_deg: Interval = Field(default_factory=lambda: [-180.0, 180.0], description="azimuth, deg")
    el_range_deg: Interval = Field(default_factory=lambda: [0.0, 30.0], description="elevation, deg")
    vb_range_mps: Interval = Field(default_factory=lambda: [-450.0, 450.0], description="bistatic velocity, m/s")

    @model_validator(mode="after")
    def _check(self) -> ClutterParams:
        for name in ("rb_range_m", "az_range_deg", "el_range_deg", "vb_range_mps"):
            _increasing(name, getattr(self, name))
        if not (self.el_range_deg[0] >= -90.0 and self.el_range_deg[1] <= 90.0):
            raise ValueError("el_range_deg must lie within [-90, 90]")
        return self

    def spec(self) -> ClutterSpec:
        def pair(v: list[float]) -> tuple[float, float]:
            return (v[0], v[1])

        return ClutterSpec(
            self.rate_per_scan,
            pair(self.rb_range_m),
            pair(self.az_range_deg),
            pair(self.el_range_deg),
            pair(self.vb_range_mps),
        )


class SigmaParams(SimParams):
    """One-sigma Gaussian measurement noise (the paper's values by default, digest §1.5)."""

    rb_m: float = Field(default=PAPER_SIGMA[0], ge=0.0, le=1e5, description="bistatic range, m")
    az_deg: float = Field(default=PAPER_SIGMA[1], ge=0.0, le=30.0, description="azimuth, deg")
    el_deg: float = Field(default=PAPER_SIGMA[2], ge=0.0, le=30.0, description="elevation, deg")
    vb_mps: float = Field(default=PAPER_SIGMA[3], ge=0.0, le=1e3, description="bistatic velocity, m/s")


class SnrParams(SimParams):
    """SNR of the plots (``simulation.SnrSpec``): fixed 20 / 13 dB, or Swerling-1 above a detection threshold."""

    model: Literal["fixed", "swerling1"] = Field(default="fixed", description="fixed: targets 20 dB, clutter 13 dB")
    threshold_db: float = Field(default=13.0, ge=-50.0, le=100.0, description="detection threshold, dB")
    target_mean_db: float = Field(default=20.0, ge=-50.0, le=100.0, description="mean SNR of target echoes, dB")
    clutter_mean_db: float = Field(default=10.0, ge=-50.0, le=100.0, description="mean clutter-to-noise, dB")

    def spec(self) -> SnrSpec:
        return SnrSpec(self.model, self.threshold_db, self.target_mean_db, self.clutter_mean_db)


class PclSimParams(SimParams):
    """Parameters of the ``pcl_tracker`` simulator (see the module doc and docs/pcl_tracker.md)."""

    receiver_id: KeyChunk = Field(default="rx1", description="receiver id (platform chunk of the sensor key)")
    illuminator_id: KeyChunk = Field(default="tx-fm-98.1", description="illuminator id (sensor id of the key)")
    tx_position_enu_m: Vec3 = Field(
        default_factory=lambda: list(PAPER_TX_M), description="transmitter relative to the receiver [E, N, U], m"
    )
    scan_period_s: float = Field(default=3.0, gt=0.0, le=3600.0, description="time between scans, s")
    start_s: float = Field(default=0.0, ge=0.0, description="time of the first scan, s")
    targets: list[TargetParams] = Field(default_factory=list, max_length=10_000)
    random_targets: RandomTargetsParams | None = Field(default=None, description="add a generated target layout")
    p_detection: float = Field(default=1.0, ge=0.0, le=1.0, description="probability a target yields a plot")
    clutter: ClutterParams = Field(default_factory=ClutterParams)
    sigma: SigmaParams = Field(default_factory=SigmaParams)
    include_sigmas: bool = Field(default=True, description="plots carry their sigmas (else the tracker defaults)")
    range_form: Literal["bistatic_range", "range_sum", "delay"] = Field(
        default="bistatic_range", description="how plots carry range: r_b, R_rx + R_tx, or delay r_b / c"
    )
    velocity_form: Literal["velocity", "doppler"] = Field(
        default="velocity", description="v_b in m/s, or Doppler f_d = v_b / (doppler_sign * wavelength)"
    )
    wavelength_m: float = Field(default=3.06, gt=0.0, le=1e4, description="illuminator wavelength, m")
    doppler_sign: Literal[-1, 1] = Field(default=-1, description="v_b = doppler_sign * wavelength * f_d")
    drop_scans: list[int] = Field(
        default_factory=list, max_length=100_000, description="scan ids (1-based) whose target plots are removed"
    )
    publish_truth: bool = Field(default=True, description="publish and register the targets' truth")
    snr: SnrParams = Field(default_factory=SnrParams)

    @model_validator(mode="after")
    def _check(self) -> PclSimParams:
        ids = [t.id for t in self.targets]
        if self.random_targets is not None:
            ids += [f"{self.random_targets.id_prefix}{i + 1}" for i in range(self.random_targets.count)]
        dup = sorted({i for i in ids if ids.count(i) > 1}) if len(ids) != len(set(ids)) else []
        if dup:
            raise ValueError(f"target ids must be unique; repeated: {dup[:10]}")
        if any(s < 1 for s in self.drop_scans):
            raise ValueError("drop_scans are 1-based scan ids")
        return self

    def target_specs(self) -> list[TargetSpec]:
        specs = [t.spec() for t in self.targets]
        rt = self.random_targets
        if rt is not None:
            layout = many_target_scenario(rt.count, seed=rt.layout_seed).targets
            specs += [
                TargetSpec(f"{rt.id_prefix}{i + 1}", *_spec_fields(s)) for i, s in enumerate(layout)
            ]  # same motion, this scenario's ids
        return specs

    def target_ids(self) -> list[str]:
        return [s.target_id for s in self.target_specs()]


def _spec_fields(
    s: TargetSpec,
) -> tuple[tuple[float, float, float], tuple[float, float, float], float, float, float, float, float]:
    return (s.p0_m, s.v0_mps, s.t_birth_s, s.t_death_s, s.turn_rate_dps, s.turn_start_s, s.turn_end_s)


class TargetTruth:
    """A target's exact truth for :class:`ScenarioContext` users (NaN while the target does not exist)."""

    def __init__(self, spec: TargetSpec) -> None:
        self.spec = spec

    def truth_at(self, stamps_ns: np.ndarray) -> TruthState:
        t = np.asarray(stamps_ns, dtype=np.float64) / NS_PER_S
        if isinstance(self.spec, TrackTargetSpec) and self.spec.track is not None:
            return _track_truth(self.spec.track, t)
        states = np.full((t.size, 6), np.nan)
        for i, ti in enumerate(t.tolist()):
            s = self.spec.state(ti)
            if s is not None:
                states[i] = s
        v = states[:, 3:]
        hspeed = np.hypot(v[:, 0], v[:, 1])
        turning = (t >= self.spec.turn_start_s) & (t < self.spec.turn_end_s)
        w = np.where(turning, math.radians(self.spec.turn_rate_dps), 0.0)
        return TruthState(
            position_m=states[:, :3],
            velocity_mps=v,
            heading_rad=np.mod(np.arctan2(v[:, 0], v[:, 1]), 2.0 * math.pi),
            pitch_rad=np.arctan2(v[:, 2], hspeed),
            roll_rad=np.arctan(hspeed * w / G_MPS2),
        )


def _track_truth(track: RecordedTrack, t: np.ndarray) -> TruthState:
    """The track's truth at times t (s), NaN outside its span (the target does not exist there)."""
    inside = (t >= track.start_s) & (t <= track.end_s)
    n = t.size
    pos, vel = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    heading, pitch, roll = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    if inside.any():
        st = track.states(t[inside])
        pos[inside], vel[inside] = st.position_m, st.velocity_mps
        heading[inside], pitch[inside], roll[inside] = st.heading_rad, st.pitch_rad, st.roll_rad
    return TruthState(pos, vel, heading, pitch, roll)


@register("pcl_tracker")
class PclSimulator:
    """Truth and bistatic scans of one receiver–illuminator pair (see the module doc)."""

    Params = PclSimParams

    def __init__(self, params: PclSimParams, rng: np.random.Generator, context: ScenarioContext) -> None:
        self.params = params
        self.rng = rng
        self.context = context
        specs = params.target_specs()
        period_ns = params.scan_period_s * NS_PER_S
        start_ns = round(params.start_s * NS_PER_S)
        n_scans = 0 if start_ns > context.duration_ns else int((context.duration_ns - start_ns) // period_ns) + 1
        while n_scans and start_ns + round((n_scans - 1) * params.scan_period_s * 1e9) > context.duration_ns:
            n_scans -= 1
        self.scenario = PclScenario(
            name=context.scenario,
            tx_position_enu_m=(params.tx_position_enu_m[0], params.tx_position_enu_m[1], params.tx_position_enu_m[2]),
            receiver_id=params.receiver_id,
            illuminator_id=params.illuminator_id,
            scan_period_s=params.scan_period_s,
            n_scans=n_scans,
            t0_ns=start_ns,
            targets=tuple(specs),
            p_detection=params.p_detection,
            clutter=params.clutter.spec(),
            sigma=(params.sigma.rb_m, params.sigma.az_deg, params.sigma.el_deg, params.sigma.vb_mps),
            include_sigmas=params.include_sigmas,
            range_form=params.range_form,
            velocity_form=params.velocity_form,
            wavelength_m=params.wavelength_m,
            doppler_sign=params.doppler_sign,
            drop_scans=tuple(params.drop_scans),
            snr=params.snr.spec(),
        )
        if params.publish_truth:
            for spec in specs:
                context.register_platform(spec.target_id, TargetTruth(spec))
        self.scan_key = input_key(params.receiver_id, params.illuminator_id)

    def events(self) -> Iterator[Event]:
        run = simulate(self.scenario, self.rng, frame_id=self.context.frame_id, source="")
        for scan, truths in zip(run.scans, run.truth, strict=True):
            stamp = scan.header.stamp_ns
            if self.params.publish_truth:
                for tr in truths:
                    yield Event(stamp, keys.truth(tr.platform), tr)
            yield Event(stamp, self.scan_key, scan)
