"""Pure truth + measurement simulation of digest 002 (§5.4 REF/LOW and robustness cases, and a fleet).

A discrete-event simulation on the true (scenario) clock, seconds from the start:

* **Field**: surveyed nodes (and base docks); the true node positions may differ from the survey.
* **Vehicles**: docked AUVs act as beacons per the latest :class:`BeaconAssignment` fed in with
  :meth:`Simulation.feed`; moving AUVs follow a polyline at constant depth, at constant speed or with a speed per leg
  and hover times at the waypoints (:class:`ProfilePath`). In a fleet scenario
  they dock at the nodes of their route, service them, report ``SERVICE_DONE`` and leave only after a
  :class:`DepartureGrant` (fed in), announcing ``DEPARTED`` with their planned route.
* **Acoustic channel**: the leader broadcasts every T_c (uniform 0-10 ms emission jitter); each follower
  detects the leader's packet (straight-line propagation at the true sound speed, detection jitter
  sigma_f), replies tau_j later on its own clock only if the packet's epoch and leader match its current
  assignment, and reports the delay it applied. Each moving AUV detects every packet at the instant its
  moving antenna meets the wavefront (solved iteratively), plus multipath delays, with independent packet
  loss and blackouts; the detection epoch is read on its own clock ``theta = b + (1 + skew) t + steps`` with
  noise sigma_t, and stamped on the data clock (true time + stamp jitter).
* **Navigation sensors** of moving AUVs: DVL speed (V (1 + k) + b: a Gauss-Markov scale factor k, 0 in the
  digest's model, and the digest's additive Gauss-Markov error b, which also acts at rest) and heading with
  Gauss-Markov + white errors (1 Hz),
  depth, and the on-board sound-speed estimate (true c + bias + white error per cycle).

Everything produced is a schema message with ``header.stamp_ns`` on the data clock, returned in stamp
order by :meth:`Simulation.advance` as :class:`Emitted` records (platform, kind, message).
"""

from __future__ import annotations

import bisect
import heapq
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy.signal import lfilter

from schemas import AcousticArrival, Attitude, Depth, Header, Message, NavPacket, SoundSpeed, SpeedLog, Truth
from schemas.rd_nav import BeaconAssignment, DepartureGrant, VehicleStatus
from services.player.simulators.recorded_track import RecordedTrack, TrackFileParams, load_cached

from .geometry import F64

#: REF layout of §4.2/§5.4 (A1 apex leader, A2, A3), NED m
APEX_X_M = math.sqrt(2900.0**2 - 1500.0**2)
REF_NODES: dict[str, tuple[float, float, float]] = {
    "n1": (APEX_X_M, 1500.0, 100.0),
    "n2": (0.0, 0.0, 100.0),
    "n3": (0.0, 3000.0, 100.0),
}
REF_BEACONS = {"auv1": "n1", "auv2": "n2", "auv3": "n3"}
REF_MOVER = "auv4"

PathName = Literal["inside", "boundary", "outside", "racetrack"]


# ============================================================================ configuration =====
class VehicleSpec(BaseModel):
    """One AUV of the scenario."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    auv_id: str
    start_node: str | None = Field(default=None, description="docked here at t = 0 (None: starts moving)")
    path: PathName | list[tuple[float, float]] | None = Field(
        default=None, description="fixed path of a mover (REF trajectories or waypoints north/east, m)"
    )
    route: list[str] = Field(default_factory=list, description="nodes to visit in order, cyclic (fleet)")
    service_s: float | None = Field(default=None, description="servicing time at a node, s (None: never done)")
    speeds_mps: list[float] | None = Field(
        default=None, description="speed on each leg of a waypoint path, m/s (None: the scenario's speed_mps)"
    )
    hold_s: list[float] | None = Field(
        default=None, description="hover time at each waypoint of a waypoint path (the first: before leaving), s"
    )
    repeat: bool = Field(default=False, description="a waypoint path starts over at its end (a named path always)")
    track: TrackFileParams | None = Field(
        default=None, description="a mover's recorded trajectory (scenario frame east/north/up), from t = 0"
    )

    @model_validator(mode="after")
    def _profile(self) -> VehicleSpec:
        if self.track is not None:
            extra = [n for n in ("start_node", "path", "speeds_mps", "hold_s", "service_s") if getattr(self, n)]
            extra += ["route"] if self.route else []
            extra += ["repeat"] if self.repeat else []
            if extra:
                raise ValueError(f"a recorded track is the whole motion of a mover: remove {', '.join(extra)}")
            if self.track.time_offset_s != 0.0:
                raise ValueError("track.time_offset_s: a mover moves from t = 0 (the track's first row)")
            return self
        if self.speeds_mps is None and self.hold_s is None and not self.repeat:
            return self
        if not isinstance(self.path, list):
            raise ValueError("speeds_mps, hold_s and repeat need a waypoint path")
        legs = len(self.path) - 1
        if self.speeds_mps is not None and (len(self.speeds_mps) != legs or min(self.speeds_mps) <= 0.0):
            raise ValueError(f"speeds_mps: one positive speed per leg ({legs})")
        if self.hold_s is not None and (len(self.hold_s) != legs + 1 or min(self.hold_s) < 0.0):
            raise ValueError(f"hold_s: one non-negative time per waypoint ({legs + 1})")
        if self.repeat and math.dist(self.path[0], self.path[-1]) > 1e-6:
            raise ValueError("a repeated path must end where it starts")
        return self


class ScenarioConfig(BaseModel):
    """All parameters of one simulated run (defaults: REF, §5.4)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = "REF-inside"
    duration_s: float = Field(default=14_400.0, gt=0.0)
    start_stamp_ns: int = Field(default=1_000_000_000_000, ge=0, description="data-clock stamp of t = 0")
    nodes: dict[str, tuple[float, float, float]] = Field(default_factory=lambda: dict(REF_NODES))
    vehicles: list[VehicleSpec] = Field(
        default_factory=lambda: [
            *(VehicleSpec(auv_id=a, start_node=n) for a, n in REF_BEACONS.items()),
            VehicleSpec(auv_id=REF_MOVER, path="inside"),
        ]
    )
    # motion
    speed_mps: float = Field(default=1.5, gt=0.0)
    auv_depth_m: float = Field(default=80.0)
    # acoustic protocol
    cycle_period_s: float = Field(default=10.0, gt=0.0)
    cycle_phase_s: float = Field(default=0.0, ge=0.0, description="first emission at this time, s")
    emit_jitter_s: float = Field(default=0.010, ge=0.0, description="uniform leader emission jitter, s")
    c_true_mps: float = Field(default=1500.0)
    sigma_t_s: float = Field(default=0.2e-3, ge=0.0, description="arrival-time noise per arrival, s")
    sigma_f_s: float = Field(default=0.0, ge=0.0, description="follower detection jitter, s")
    follower_skew_ppm: float = Field(default=0.0)
    # receiver clock
    clock_offset_max_s: float = Field(default=1000.0, ge=0.0)
    clock_skew_ppm: float = Field(default=0.0)
    clock_steps: list[tuple[float, float]] = Field(default_factory=list, description="(true time, step) s")
    stamp_jitter_s: float = Field(default=1e-3, ge=0.0, description="data-clock stamp jitter of arrivals, s")
    # channel faults
    packet_loss: float = Field(default=0.0, ge=0.0, le=1.0, description="per packet and receiver")
    loss_at_followers: bool = Field(
        default=False, description="followers can also miss the leader packet (the REF figures: only the AUV)"
    )
    multipath_prob: float = Field(default=0.0, ge=0.0, le=1.0)
    multipath_delay_s: tuple[float, float] = Field(default=(0.002, 0.050))
    blackouts: list[tuple[float, float]] = Field(default_factory=list, description="(t0, t1) no reception, s")
    node_error_sigma_m: float = Field(default=0.0, ge=0.0, description="true - surveyed node, per axis, m")
    # sound speed estimate on the AUV
    sigma_c_est_mps: float = Field(default=0.3, ge=0.0, description="white error per cycle, m/s")
    c_bias_mps: float = Field(default=0.0)
    sigma_c_reported_mps: float | None = Field(default=None, description="sigma in SoundSpeed (None: as above)")
    # DR sensors (§5.4)
    sensor_period_s: float = Field(default=1.0, gt=0.0)
    speed_gm_sigma_mps: float = Field(
        default=0.05, ge=0.0, description="additive speed error (DVL bias), Gauss-Markov sigma, m/s: the digest's"
    )
    speed_gm_tau_s: float = 300.0
    speed_white_mps: float = 0.02
    speed_scale_gm_sigma: float = Field(
        default=0.0, ge=0.0, description="speed scale-factor error, Gauss-Markov sigma (fraction of the speed) [E]"
    )
    speed_scale_gm_tau_s: float = Field(default=300.0, gt=0.0, description="its correlation time, s [E]")
    heading_gm_sigma_deg: float = 2.0
    heading_gm_tau_s: float = 300.0
    heading_white_deg: float = 0.5
    dvl_dropouts: list[tuple[float, float]] = Field(default_factory=list, description="no bottom lock, s")
    depth_period_s: float = Field(default=10.0, gt=0.0)
    depth_sigma_m: float = Field(default=0.0, ge=0.0)
    truth_period_s: float = Field(default=0.0, ge=0.0, description="Truth messages (0: none)")
    truth_at_leader_arrivals: bool = Field(
        default=False, description="also a Truth of a moving AUV at the stamp of each leader packet it receives"
    )
    truth_axes: Literal["ned", "enu"] = Field(
        default="ned", description="Truth positions [north, east, depth] (ned) or [east, north, up] (enu)"
    )
    truth_frame_id: str = Field(default="base_ned", description="header.frame_id of the Truth messages")
    # fleet behaviour
    undock_delay_s: float = Field(default=20.0, ge=0.0)
    heartbeat_period_s: float = Field(default=0.0, ge=0.0, description="HEARTBEAT statuses (0: none)")
    base_listener: bool = Field(default=False, description="also emit arrivals at the base (coordinator)")
    base_position_ned_m: tuple[float, float, float] = (0.0, 0.0, 100.0)
    tau_s: list[float] = Field(default_factory=lambda: [0.5, 3.5], description="reply slots, s")


def ref(path: PathName = "inside", **overrides: object) -> ScenarioConfig:
    """REF scenario of §5.4 with the mover on one of its trajectories."""
    vehicles = [
        *(VehicleSpec(auv_id=a, start_node=n) for a, n in REF_BEACONS.items()),
        VehicleSpec(auv_id=REF_MOVER, path=path),
    ]
    base: dict[str, object] = {"name": f"REF-{path}", "vehicles": vehicles}
    if path == "racetrack":
        base["duration_s"] = 7200.0
    base.update(overrides)
    return ScenarioConfig.model_validate(base)


def low(path: PathName = "inside", **overrides: object) -> ScenarioConfig:
    """LOW = REF with sigma_t = 0.1 ms and sigma_c = 0.1 m/s (§6)."""
    kw: dict[str, object] = {"sigma_t_s": 0.1e-3, "sigma_c_est_mps": 0.1, "name": f"LOW-{path}"}
    kw.update(overrides)
    return ref(path, **kw)


FLEET_NODES: dict[str, tuple[float, float, float]] = {
    "n0": (0.0, 0.0, 100.0),
    **{
        f"n{k + 1}": (
            round(2000.0 * math.cos(math.radians(60 * k)), 3),
            round(2000.0 * math.sin(math.radians(60 * k)), 3),
            100.0,
        )
        for k in range(6)
    },
    "base/auv7": (-300.0, 200.0, 100.0),
}


def fleet(**overrides: object) -> ScenarioConfig:
    """A servicing fleet (§2.4): six AUVs docked at a hexagon of nodes, one at the base; two of them
    service their node, then travel to the centre node and back, leaving only with a departure grant."""
    vehicles = [
        VehicleSpec(auv_id="auv1", start_node="n1", route=["n0", "n1"], service_s=300.0),
        VehicleSpec(auv_id="auv2", start_node="n2", service_s=None),
        VehicleSpec(auv_id="auv3", start_node="n3", route=["n0", "n3"], service_s=2400.0),
        *(VehicleSpec(auv_id=f"auv{k}", start_node=f"n{k}") for k in (4, 5, 6)),
        VehicleSpec(auv_id="auv7", start_node="base/auv7"),
    ]
    base: dict[str, object] = {
        "name": "fleet",
        "duration_s": 3600.0,
        "nodes": dict(FLEET_NODES),
        "vehicles": vehicles,
        "base_listener": True,
        "heartbeat_period_s": 60.0,
        "base_position_ned_m": (-300.0, 200.0, 100.0),
    }
    base.update(overrides)
    return ScenarioConfig.model_validate(base)


def ref_assignment(cfg: ScenarioConfig, stamp_ns: int | None = None, epoch: int = 1) -> BeaconAssignment:
    """The REF active set: leader at the apex (auv1 on n1), followers auv2, auv3 with tau = 0.5, 3.5 s."""
    members = ["auv1", "auv2", "auv3"]
    pos = [list(cfg.nodes[REF_BEACONS[a]]) for a in members]
    return BeaconAssignment(
        header=Header(stamp_ns=cfg.start_stamp_ns if stamp_ns is None else stamp_ns, frame_id="base_ned"),
        epoch=epoch,
        leader_id="auv1",
        follower_ids=["auv2", "auv3"],
        tau_s=list(cfg.tau_s[:2]),
        cycle_period_s=cfg.cycle_period_s,
        positions_ned_m=pos,
        reason="REF",
    )


# ============================================================================ paths =====
def polygon(center: tuple[float, float], radius: float, n: int) -> list[tuple[float, float]]:
    return [
        (center[0] + radius * math.cos(2 * math.pi * k / n), center[1] + radius * math.sin(2 * math.pi * k / n))
        for k in range(n + 1)
    ]


def ref_path(name: PathName, nodes: dict[str, tuple[float, float, float]]) -> list[tuple[float, float]]:
    """Waypoints (north, east) of the §5.4 trajectories; each is repeated until the end of the run."""
    a1, a2, a3 = (nodes[k][:2] for k in ("n1", "n2", "n3"))
    if name == "inside":  # 72-gon of radius 600 m around (827, 1500)
        return polygon((827.0, 1500.0), 600.0, 72)
    if name == "boundary":  # the edges A2 -> A1 -> A3 -> A2
        return [a2, a1, a3, a2]
    if name == "outside":  # lawnmower south of A2-A3: legs along east, 400 m apart, out and back
        xs = [-500.0, -900.0, -1300.0, -1500.0]
        pts: list[tuple[float, float]] = []
        for i, x in enumerate(xs):
            ys = (200.0, 2800.0) if i % 2 == 0 else (2800.0, 200.0)
            pts += [(x, ys[0]), (x, ys[1])]
        return pts + pts[-2::-1]
    if name == "racetrack":  # through the apex region to 1.5 km beyond A1 (T-ROB-12)
        return [(1500.0, 1700.0), (4000.0, 1700.0), (4000.0, 1300.0), (1500.0, 1300.0), (1500.0, 1700.0)]
    raise ValueError(name)


class Path:
    """Constant-speed polyline in the horizontal plane, optionally repeated; instantaneous turns."""

    def __init__(self, waypoints: list[tuple[float, float]], t_start: float, speed: float, repeat: bool) -> None:
        wp = np.asarray(waypoints, dtype=np.float64)
        seg = np.diff(wp, axis=0)
        length = np.hypot(seg[:, 0], seg[:, 1])
        keep = length > 1e-9
        self.wp = np.vstack([wp[:1], wp[1:][keep]])
        seg, length = seg[keep], length[keep]
        self.u = seg / length[:, None]
        self.cum = np.concatenate([[0.0], np.cumsum(length)])
        self.total = float(self.cum[-1])
        self.t_start = t_start
        self.speed = speed
        self.repeat = repeat
        self._cum = self.cum.tolist()
        self._wp = self.wp.tolist()
        self._u = self.u.tolist()

    @property
    def t_end(self) -> float:
        return math.inf if self.repeat else self.t_start + self.total / self.speed

    def _arc(self, t: float) -> tuple[float, bool]:
        s = max(t - self.t_start, 0.0) * self.speed
        if self.repeat:
            return s % self.total, True
        return min(s, self.total), s < self.total

    def state(self, t: float) -> tuple[float, float, float, float]:
        """(north, east, heading rad, speed m/s) at true time t."""
        s, moving = self._arc(t)
        k = min(bisect.bisect_right(self._cum, s) - 1, len(self._u) - 1)
        ds = s - self._cum[k]
        ux, uy = self._u[k]
        x0, y0 = self._wp[k]
        return x0 + ds * ux, y0 + ds * uy, math.atan2(uy, ux), (self.speed if moving else 0.0)

    def positions(self, t: F64) -> F64:
        """Vectorised positions (n, 2)."""
        s = np.maximum(t - self.t_start, 0.0) * self.speed
        s = np.mod(s, self.total) if self.repeat else np.minimum(s, self.total)
        k = np.clip(np.searchsorted(self.cum, s, side="right") - 1, 0, len(self.u) - 1)
        return self.wp[k] + (s - self.cum[k])[:, None] * self.u[k]


class ProfilePath:
    """A polyline flown with a speed per leg and a hover time at each waypoint, optionally repeated.

    The timeline alternates holds and legs: hold at waypoint 0, leg 0 -> 1, hold at waypoint 1, ... Speed
    changes and turns are instantaneous (as in :class:`Path`). While hovering the vehicle keeps the heading
    of the leg it arrived on (at waypoint 0: of the first leg) and its true speed is 0. Without ``repeat`` it
    hovers at the last waypoint after the end.
    """

    def __init__(
        self,
        waypoints: list[tuple[float, float]],
        t_start: float,
        speeds_mps: list[float],
        hold_s: list[float],
        repeat: bool,
    ) -> None:
        wp = np.asarray(waypoints, dtype=np.float64)
        if wp.shape[0] < 2 or len(speeds_mps) != wp.shape[0] - 1 or len(hold_s) != wp.shape[0]:
            raise ValueError("one speed per leg and one hold time per waypoint")
        # segments: (t0, duration, start point, unit vector, speed, heading)
        segs: list[tuple[float, float, tuple[float, float], tuple[float, float], float, float]] = []
        t = 0.0
        heading = None
        for k in range(wp.shape[0]):
            nxt = wp[k + 1] - wp[k] if k + 1 < wp.shape[0] else None
            length = float(np.hypot(*nxt)) if nxt is not None else 0.0
            if heading is None:  # hover before the first leg: its heading
                first = next(wp[j + 1] - wp[j] for j in range(wp.shape[0] - 1) if np.hypot(*(wp[j + 1] - wp[j])) > 0)
                heading = math.atan2(float(first[1]), float(first[0]))
            if hold_s[k] > 0.0:
                segs.append((t, hold_s[k], (float(wp[k][0]), float(wp[k][1])), (0.0, 0.0), 0.0, heading))
                t += hold_s[k]
            if nxt is not None and length > 1e-9:
                u = (float(nxt[0]) / length, float(nxt[1]) / length)
                heading = math.atan2(u[1], u[0])
                dur = length / speeds_mps[k]
                segs.append((t, dur, (float(wp[k][0]), float(wp[k][1])), u, speeds_mps[k], heading))
                t += dur
        self._segs = segs
        self._t0 = [sg[0] for sg in segs]
        self.period = t
        self.t_start = t_start
        self.repeat = repeat
        self._last = (float(wp[-1][0]), float(wp[-1][1]), heading if heading is not None else 0.0)

    @property
    def t_end(self) -> float:
        return math.inf if self.repeat else self.t_start + self.period

    def state(self, t: float) -> tuple[float, float, float, float]:
        """(north, east, heading rad, speed m/s) at true time t."""
        tau = max(t - self.t_start, 0.0)
        if self.repeat:
            tau = tau % self.period
        elif tau >= self.period:
            x, y, h = self._last
            return x, y, h, 0.0
        k = max(bisect.bisect_right(self._t0, tau) - 1, 0)
        t0, _, p0, u, v, h = self._segs[k]
        ds = (tau - t0) * v
        return p0[0] + ds * u[0], p0[1] + ds * u[1], h, v

    def positions(self, t: F64) -> F64:
        return np.array([self.state(float(x))[:2] for x in np.asarray(t).ravel()]).reshape(-1, 2)


class TrackPath:
    """A recorded trajectory as a mover's path (the interface of :class:`Path`): the track's east/north/up in
    the scenario frame are NED north = north, east = east, depth = -up. ``state`` gives the heading of the
    track (recorded, else the course of the velocity) and the horizontal speed, which the DR sensors measure
    along that heading; times outside the recorded span are clamped to it (the run ends with the track)."""

    def __init__(self, track: RecordedTrack) -> None:
        self.track = track
        self.t_start = track.start_s

    @property
    def t_end(self) -> float:
        return self.track.end_s

    def _states(self, t: F64) -> tuple[F64, F64, F64, F64, F64]:
        st = self.track.states(np.clip(np.asarray(t, dtype=np.float64), self.track.start_s, self.track.end_s))
        p = st.position_m
        return p[:, 1], p[:, 0], st.heading_rad, st.speed_mps, -p[:, 2]

    def state(self, t: float) -> tuple[float, float, float, float]:
        """(north, east, heading rad, speed m/s) at true time t."""
        x, y, h, v, _ = self._states(np.array([t]))
        return float(x[0]), float(y[0]), float(h[0]), float(v[0])

    def depth(self, t: float) -> float:
        """Depth (m, + down) at true time t."""
        return float(self._states(np.array([t]))[4][0])

    def positions(self, t: F64) -> F64:
        x, y, _, _, _ = self._states(np.atleast_1d(np.asarray(t, dtype=np.float64)))
        return np.column_stack([x, y])


# ============================================================================ engine =====
@dataclass(frozen=True)
class Emitted:
    """One simulated message with where it comes from: ``platform`` and ``kind`` name its sensor key."""

    platform: str
    kind: str  # dvl, attitude, depth, sound_speed, acoustic, status, truth
    msg: Message


class _Normals:
    """Block-drawn standard normals (cheap scalar draws)."""

    def __init__(self, rng: np.random.Generator, block: int = 4096) -> None:
        self.rng = rng
        self.block = block
        self._buf: list[float] = []

    def __call__(self) -> float:
        if not self._buf:
            self._buf = self.rng.standard_normal(self.block).tolist()
        return self._buf.pop()


class DrSensorErrors:
    """Speed and heading errors of one AUV's DR sensors (§5.4): first-order Gauss-Markov + white, per sample.

    Drawn in vectorised blocks (``block``) so that a test can generate many runs at once with exactly the
    model the simulation uses sample by sample (``next``).
    """

    def __init__(self, cfg: ScenarioConfig, rng: np.random.Generator, block: int = 3600) -> None:
        self.cfg = cfg
        self.rng = rng
        self.block_len = block
        self.gm_v = cfg.speed_gm_sigma_mps * float(rng.standard_normal())
        self.gm_h = math.radians(cfg.heading_gm_sigma_deg) * float(rng.standard_normal())
        self._dv: list[float] = []
        self._dh: list[float] = []
        self._rng_scale: np.random.Generator | None = None
        self._scale = 0.0

    def block(self, n: int) -> tuple[F64, F64]:
        """The next n samples (speed error m/s, heading error rad)."""
        cfg = self.cfg
        dt = cfg.sensor_period_s
        w = self.rng.standard_normal((4, n))
        out = []
        for row, (sig, tau, white, attr) in enumerate(
            [
                (cfg.speed_gm_sigma_mps, cfg.speed_gm_tau_s, cfg.speed_white_mps, "gm_v"),
                (
                    math.radians(cfg.heading_gm_sigma_deg),
                    cfg.heading_gm_tau_s,
                    math.radians(cfg.heading_white_deg),
                    "gm_h",
                ),
            ]
        ):
            a = math.exp(-dt / tau)
            b = sig * math.sqrt(1.0 - a * a)
            gm, _ = lfilter([b], [1.0, -a], w[2 * row], zi=[a * getattr(self, attr)])
            setattr(self, attr, float(gm[-1]))
            out.append(gm + white * w[2 * row + 1])
        return out[0], out[1]

    def next(self) -> tuple[float, float]:
        if not self._dv:
            dv, dh = self.block(self.block_len)
            self._dv, self._dh = dv.tolist()[::-1], dh.tolist()[::-1]
        return self._dv.pop(), self._dh.pop()

    def next_scale(self) -> float:
        """The speed scale-factor error of the next sample (Gauss-Markov; its own stream, so that the digest's
        additive errors stay the same draws whether or not a scale error is simulated)."""
        cfg = self.cfg
        if cfg.speed_scale_gm_sigma <= 0.0:
            return 0.0
        if self._rng_scale is None:
            seq = self.rng.bit_generator.seed_seq
            child = seq.spawn(1)[0] if isinstance(seq, np.random.SeedSequence) else np.random.SeedSequence(0)
            self._rng_scale = np.random.default_rng(child)
            self._scale = cfg.speed_scale_gm_sigma * float(self._rng_scale.standard_normal())
            return self._scale
        a = math.exp(-cfg.sensor_period_s / cfg.speed_scale_gm_tau_s)
        w = float(self._rng_scale.standard_normal())
        self._scale = a * self._scale + cfg.speed_scale_gm_sigma * math.sqrt(1.0 - a * a) * w
        return self._scale


@dataclass
class _Vehicle:
    auv_id: str
    spec: VehicleSpec
    state: str  # DOCKED, DONE, TRANSIT
    node_id: str | None
    path: Path | ProfilePath | TrackPath | None = None
    transmitting: bool = False
    route_idx: int = 0
    clock_offset_s: float = 0.0
    clock_skew: float = 0.0
    errors: DrSensorErrors | None = None
    normals: _Normals | None = None
    sensor_seq: int = 0
    depth_m: float = 80.0


@dataclass(order=True)
class _Event:
    t: float
    n: int
    fn: Callable[[], None] = field(compare=False)


class Simulation:
    """Event-driven simulation; :meth:`advance` returns the messages up to a time in stamp order."""

    def __init__(self, cfg: ScenarioConfig, seed: int | np.random.SeedSequence = 0) -> None:
        self.cfg = cfg
        ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
        streams = ss.spawn(8 + len(cfg.vehicles))
        self.rng_nodes = np.random.default_rng(streams[0])
        self.rng_clock = np.random.default_rng(streams[1])
        self.rng_ac = np.random.default_rng(streams[2])
        self.rng_loss = np.random.default_rng(streams[3])
        self.rng_c = np.random.default_rng(streams[4])
        self.rng_emit = np.random.default_rng(streams[5])
        self.nrm_ac = _Normals(self.rng_ac)
        self.now = 0.0
        self._events: list[_Event] = []
        self._out: list[tuple[int, int, Emitted]] = []
        self._n = 0
        self.assignment: BeaconAssignment | None = None
        self.surveyed = {k: np.array(v, dtype=np.float64) for k, v in cfg.nodes.items()}
        self.true_nodes = {
            k: v + (self.rng_nodes.normal(0.0, cfg.node_error_sigma_m, 3) if cfg.node_error_sigma_m > 0 else 0.0)
            for k, v in self.surveyed.items()
        }
        self.vehicles: dict[str, _Vehicle] = {}
        self.protocol_violations: list[str] = []
        self.emissions = 0
        self.granted: dict[str, float] = {}
        for i, spec in enumerate(cfg.vehicles):
            rng_v = np.random.default_rng(streams[8 + i])
            v = _Vehicle(
                auv_id=spec.auv_id,
                spec=spec,
                state="DOCKED" if spec.start_node else "TRANSIT",
                node_id=spec.start_node,
                clock_offset_s=float(self.rng_clock.uniform(1.0, 1.0 + cfg.clock_offset_max_s)),
                clock_skew=cfg.clock_skew_ppm * 1e-6,
                errors=DrSensorErrors(cfg, rng_v),
                normals=_Normals(np.random.default_rng(streams[8 + i].spawn(1)[0])),
                depth_m=cfg.auv_depth_m,
            )
            self.vehicles[spec.auv_id] = v
        self._at(0.0, self._start)
        self._at(cfg.cycle_phase_s, self._cycle)
        self._at(cfg.cycle_phase_s - 0.5 if cfg.cycle_phase_s >= 0.5 else 0.0, self._sound_speed)
        if cfg.truth_period_s > 0:
            self._at(0.0, self._truth)
        if cfg.heartbeat_period_s > 0:
            self._at(cfg.heartbeat_period_s, self._heartbeat)

    # ----- public ----------------------------------------------------------------------------
    def stamp_ns(self, t: float) -> int:
        return self.cfg.start_stamp_ns + round(t * 1e9)

    def time_of(self, stamp_ns: int) -> float:
        return (stamp_ns - self.cfg.start_stamp_ns) * 1e-9

    def feed(self, msg: Message) -> None:
        """Apply a coordinator message at the current simulation time."""
        if isinstance(msg, BeaconAssignment):
            if self.assignment is None or msg.epoch > self.assignment.epoch:
                self.assignment = msg
                for m in [msg.leader_id, *msg.follower_ids]:
                    v = self.vehicles.get(m)
                    if v is None or v.state == "TRANSIT" or not v.transmitting:
                        self.protocol_violations.append(f"{self.now:.1f}: assignment names non-beacon {m}")
        elif isinstance(msg, DepartureGrant):
            v = self.vehicles.get(msg.auv_id)
            if v is None or v.state == "TRANSIT":
                self.protocol_violations.append(f"{self.now:.1f}: grant to non-docked {msg.auv_id}")
                return
            v.transmitting = False  # stop transmitting before leaving the dock (§7.3 S1)
            self.granted[v.auv_id] = self.now
            a = self.assignment
            if a is not None and v.auv_id in (a.leader_id, *a.follower_ids):
                self.protocol_violations.append(f"{self.now:.1f}: {v.auv_id} granted while in the active set")
            self._at(self.now + self.cfg.undock_delay_s, lambda v=v: self._depart(v))  # type: ignore[misc]

    def advance(self, until_s: float) -> list[Emitted]:
        """Run every event up to ``until_s`` and return the messages stamped up to then, in stamp order."""
        while self._events and self._events[0].t <= until_s:
            ev = heapq.heappop(self._events)
            self.now = ev.t
            ev.fn()
        self.now = max(self.now, until_s)
        limit = self.stamp_ns(until_s)
        out: list[Emitted] = []
        while self._out and self._out[0][0] <= limit:
            out.append(heapq.heappop(self._out)[2])
        return out

    def truth_xy(self, auv_id: str, t: float) -> tuple[float, float]:
        v = self.vehicles[auv_id]
        if v.state != "TRANSIT" or v.path is None:
            node = v.node_id
            assert node is not None
            p = self.true_nodes[node]
            return float(p[0]), float(p[1])
        x, y, _, _ = v.path.state(t)
        return x, y

    def movers(self) -> list[str]:
        return [v.auv_id for v in self.vehicles.values() if v.state == "TRANSIT"]

    # ----- scheduling ------------------------------------------------------------------------
    def _at(self, t: float, fn: Callable[[], None]) -> None:
        self._n += 1
        heapq.heappush(self._events, _Event(t, self._n, fn))

    def _emit(self, t: float, platform: str, kind: str, msg: Message) -> None:
        self._n += 1
        heapq.heappush(self._out, (msg.header.stamp_ns, self._n, Emitted(platform, kind, msg)))

    def _header(self, t: float, frame: str) -> Header:
        return Header(stamp_ns=self.stamp_ns(t), frame_id=frame, source="sim/rd_nav")

    # ----- vehicles --------------------------------------------------------------------------
    def _start(self) -> None:
        for v in self.vehicles.values():
            if v.state == "DOCKED":
                v.transmitting = True
                self._status(v, self._dock_event(v.node_id), v.node_id)
                if v.spec.service_s is not None:
                    self._at(v.spec.service_s, lambda v=v: self._service_done(v))  # type: ignore[misc]
            else:
                spec = v.spec
                if spec.track is not None:
                    v.path = TrackPath(load_cached(spec.track))
                    route = v.path.positions(np.linspace(v.path.t_start, v.path.t_end, 32))
                    x, y, _, _ = v.path.state(0.0)
                    z = v.path.depth(0.0)
                    self._status(v, "DEPARTED", None, position=[x, y, z], route=[[*p, z] for p in route.tolist()])
                    self._begin_sensors(v, 0.0)
                    continue
                if spec.path is None:
                    raise ValueError(f"{v.auv_id} starts moving without a path")
                wps = ref_path(spec.path, self.cfg.nodes) if isinstance(spec.path, str) else list(spec.path)
                repeat = isinstance(spec.path, str) or spec.repeat
                if spec.speeds_mps is None and spec.hold_s is None:
                    v.path = Path(wps, 0.0, self.cfg.speed_mps, repeat)
                else:
                    legs = len(wps) - 1
                    speeds = spec.speeds_mps or [self.cfg.speed_mps] * legs
                    v.path = ProfilePath(wps, 0.0, speeds, spec.hold_s or [0.0] * (legs + 1), repeat)
                x, y, _, _ = v.path.state(0.0)
                self._status(v, "DEPARTED", None, position=[x, y, v.depth_m], route=[[*p, v.depth_m] for p in wps[:32]])
                self._begin_sensors(v, 0.0)

    def _status(
        self,
        v: _Vehicle,
        event: str,
        node: str | None,
        position: list[float] | None = None,
        route: list[list[float]] | None = None,
    ) -> None:
        msg = VehicleStatus(
            header=self._header(self.now, "base_ned"),
            auv_id=v.auv_id,
            event=event,  # type: ignore[arg-type]
            node_id=node,
            position_ned_m=position,
            planned_route_ned_m=route or [],
            speed_mps=self.cfg.speed_mps if event == "DEPARTED" else None,
        )
        self._emit(self.now, v.auv_id, "status", msg)

    @staticmethod
    def _dock_event(node: str | None) -> str:
        return "AT_BASE" if node is not None and node.split("/")[0] == "base" else "DOCKED"

    def _service_done(self, v: _Vehicle) -> None:
        if v.state == "DOCKED":
            v.state = "DONE"
            self._status(v, "SERVICE_DONE", v.node_id)

    def _depart(self, v: _Vehicle) -> None:
        route = v.spec.route
        if not route or v.node_id is None:
            return
        here = v.node_id
        target = route[v.route_idx % len(route)]
        if target == here:
            v.route_idx += 1
            target = route[v.route_idx % len(route)]
        v.route_idx += 1
        p0 = self.surveyed[here][:2]
        p1 = self.surveyed[target][:2]
        v.path = Path([tuple(p0), tuple(p1)], self.now, self.cfg.speed_mps, repeat=False)
        v.state = "TRANSIT"
        v.transmitting = False
        start = [float(p0[0]), float(p0[1]), float(self.surveyed[here][2])]
        self._status(v, "DEPARTED", here, position=start, route=[[float(p1[0]), float(p1[1]), v.depth_m]])
        v.node_id = target
        self._at(v.path.t_end, lambda v=v: self._arrive(v))  # type: ignore[misc]
        self._begin_sensors(v, self.now)

    def _arrive(self, v: _Vehicle) -> None:
        v.state = "DOCKED"
        v.path = None
        v.transmitting = True
        self._status(v, self._dock_event(v.node_id), v.node_id)
        if v.spec.service_s is not None:
            self._at(self.now + v.spec.service_s, lambda v=v: self._service_done(v))  # type: ignore[misc]

    def _heartbeat(self) -> None:
        for v in self.vehicles.values():
            if v.state == "TRANSIT" and v.path is not None:
                x, y, _, _ = v.path.state(self.now)
                self._status(v, "HEARTBEAT", None, position=[x, y, self._depth(v, self.now)])
            else:
                self._status(v, "HEARTBEAT", v.node_id)
        self._at(self.now + self.cfg.heartbeat_period_s, self._heartbeat)

    @staticmethod
    def _depth(v: _Vehicle, t: float) -> float:
        """A moving vehicle's true depth at time t: its recorded track's, else the transit depth."""
        return v.path.depth(t) if isinstance(v.path, TrackPath) else v.depth_m

    # ----- navigation sensors ----------------------------------------------------------------
    def _begin_sensors(self, v: _Vehicle, t: float) -> None:
        v.sensor_seq += 1
        seq = v.sensor_seq
        self._at(t, lambda: self._sensor_tick(v, seq))
        self._at(t, lambda: self._depth_tick(v, seq))

    def _in(self, windows: list[tuple[float, float]], t: float) -> bool:
        return any(a <= t < b for a, b in windows)

    def _sensor_tick(self, v: _Vehicle, seq: int) -> None:
        if v.state != "TRANSIT" or v.sensor_seq != seq or v.path is None:
            return
        cfg = self.cfg
        assert v.errors is not None
        dt = cfg.sensor_period_s
        dv, dh = v.errors.next()
        ds = v.errors.next_scale()
        _, _, heading, speed = v.path.state(self.now)
        v_meas = speed * (1.0 + ds) + dv
        h_meas = heading + dh
        h_meas = math.atan2(math.sin(h_meas), math.cos(h_meas))
        hdr = self._header(self.now, f"{v.auv_id}/body")
        lock = not self._in(cfg.dvl_dropouts, self.now)
        self._emit(
            self.now,
            v.auv_id,
            "dvl",
            SpeedLog(header=hdr, v_forward_mps=v_meas, v_starboard_mps=0.0, avg_interval_s=dt, bottom_lock=lock),
        )
        self._emit(
            self.now, v.auv_id, "attitude", Attitude(header=hdr, heading_rad=h_meas, pitch_rad=0.0, roll_rad=0.0)
        )
        self._at(self.now + dt, lambda: self._sensor_tick(v, seq))

    def _depth_tick(self, v: _Vehicle, seq: int) -> None:
        if v.state != "TRANSIT" or v.sensor_seq != seq:
            return
        n = v.normals
        assert n is not None
        z = self._depth(v, self.now) + self.cfg.depth_sigma_m * n()
        self._emit(self.now, v.auv_id, "depth", Depth(header=self._header(self.now, f"{v.auv_id}/body"), depth_m=z))
        self._at(self.now + self.cfg.depth_period_s, lambda: self._depth_tick(v, seq))

    def _sound_speed(self) -> None:
        cfg = self.cfg
        for v in self.vehicles.values():
            if v.state != "TRANSIT":
                continue
            c = cfg.c_true_mps + cfg.c_bias_mps + cfg.sigma_c_est_mps * float(self.rng_c.standard_normal())
            sig = cfg.sigma_c_reported_mps if cfg.sigma_c_reported_mps is not None else cfg.sigma_c_est_mps
            msg = SoundSpeed(
                header=self._header(self.now, f"{v.auv_id}/body"), c_mps=c, sigma_c_mps=max(sig, 1e-3), model="sim"
            )
            self._emit(self.now, v.auv_id, "sound_speed", msg)
        self._at(self.now + cfg.cycle_period_s, self._sound_speed)

    def _truth(self) -> None:
        for v in self.vehicles.values():
            self._emit(self.now, v.auv_id, "truth", self._truth_msg(v, self.now))
        self._at(self.now + self.cfg.truth_period_s, self._truth)

    def _truth_msg(self, v: _Vehicle, t: float) -> Truth:
        """The true state of one vehicle at time t: position, velocity, heading (``truth_axes`` convention)."""
        moving = v.state == "TRANSIT" and v.path is not None
        if moving:
            assert v.path is not None
            x, y, heading, speed = v.path.state(t)
            z = self._depth(v, t)
        else:
            x, y = self.truth_xy(v.auv_id, t)
            z = float(self.true_nodes[v.node_id or ""][2])
            heading, speed = 0.0, 0.0
        vx, vy = speed * math.cos(heading), speed * math.sin(heading)
        if self.cfg.truth_axes == "enu":
            pos, vel = [y, x, -z], [vy, vx, 0.0]
            att = [heading % (2.0 * math.pi), 0.0, 0.0]
        else:
            pos, vel = [x, y, z], [vx, vy, 0.0]
            att = [math.atan2(math.sin(heading), math.cos(heading)), 0.0, 0.0]
        return Truth(
            header=self._header(t, self.cfg.truth_frame_id),
            platform=v.auv_id,
            position_m=pos,
            velocity_mps=vel,
            attitude_rad=att,
            extra={"depth_m": z, "moving": 1.0 if moving else 0.0},
        )

    # ----- acoustic channel ------------------------------------------------------------------
    def _clock(self, v: _Vehicle, t: float) -> float:
        steps = sum(s for ts, s in self.cfg.clock_steps if t >= ts)
        return v.clock_offset_s + (1.0 + v.clock_skew) * t + steps

    def _lost(self) -> bool:
        p = self.cfg.packet_loss
        return p > 0.0 and float(self.rng_loss.random()) < p

    def _cycle(self) -> None:
        cfg = self.cfg
        k = round((self.now - cfg.cycle_phase_s) / cfg.cycle_period_s)
        self._at(self.now + cfg.cycle_period_s, self._cycle)
        a = self.assignment
        if a is None:
            return
        leader = self.vehicles.get(a.leader_id)
        if leader is None or not leader.transmitting or leader.node_id is None:
            return
        t_tx = self.now + float(self.rng_emit.uniform(0.0, cfg.emit_jitter_s))
        self.emissions += 1
        node = leader.node_id
        pk = NavPacket(
            sender_id=leader.auv_id,
            kind="LEADER",
            leader_id=leader.auv_id,
            cycle_seq=k % 2**16,
            assignment_epoch=a.epoch,
            node_id=node,
            pos_ned_m=self.surveyed[node].tolist(),
            pos_sigma_m=0.0,
        )
        src = self.true_nodes[node]
        self._propagate(pk, src, t_tx)
        for fid in a.follower_ids:
            fv = self.vehicles.get(fid)
            if fv is None or fv.node_id is None or not fv.transmitting:
                continue
            if cfg.loss_at_followers and self._lost():
                continue
            r = float(np.linalg.norm(self.true_nodes[fv.node_id] - src))
            t_det = t_tx + r / cfg.c_true_mps + cfg.sigma_f_s * self.nrm_ac()
            self._at(max(t_det, self.now), lambda fv=fv, pk=pk, t_det=t_det: self._follower_reply(fv, pk, t_det))  # type: ignore[misc]

    def _follower_reply(self, fv: _Vehicle, lead: NavPacket, t_det: float) -> None:
        a = self.assignment
        if a is None or not fv.transmitting or fv.node_id is None:
            return
        if a.epoch != lead.assignment_epoch or a.leader_id != lead.leader_id or fv.auv_id not in a.follower_ids:
            return  # reply only to the assigned leader with a matching epoch (§7.3 S1)
        tau = a.tau_s[a.follower_ids.index(fv.auv_id)]
        t_tx = t_det + tau / (1.0 + self.cfg.follower_skew_ppm * 1e-6)
        node = fv.node_id
        pk = NavPacket(
            sender_id=fv.auv_id,
            kind="FOLLOWER",
            leader_id=lead.leader_id,
            cycle_seq=lead.cycle_seq,
            assignment_epoch=lead.assignment_epoch,
            node_id=node,
            pos_ned_m=self.surveyed[node].tolist(),
            pos_sigma_m=0.0,
            reply_delay_s=tau,
        )
        self._at(t_tx, lambda: self._propagate(pk, self.true_nodes[node], t_tx))

    def _propagate(self, pk: NavPacket, src: F64, t_tx: float) -> None:
        """Arrivals of one packet at every moving AUV (and at the base listener)."""
        cfg = self.cfg
        c = cfg.c_true_mps
        for v in self.vehicles.values():
            if v.state != "TRANSIT" or v.path is None:
                continue
            if self._in(cfg.blackouts, t_tx) or self._lost():
                continue
            t = t_tx
            for _ in range(4):  # moving receiver: solve |X(t) - src| = c (t - t_tx)
                x, y, _, _ = v.path.state(t)
                rho = math.sqrt((x - src[0]) ** 2 + (y - src[1]) ** 2 + (self._depth(v, t) - src[2]) ** 2)
                t = t_tx + rho / c
            if cfg.multipath_prob > 0 and float(self.rng_loss.random()) < cfg.multipath_prob:
                t += float(self.rng_loss.uniform(*cfg.multipath_delay_s))
            theta = self._clock(v, t) + cfg.sigma_t_s * self.nrm_ac()
            stamp_t = t + (float(self.rng_ac.uniform(-1.0, 1.0)) * cfg.stamp_jitter_s if cfg.stamp_jitter_s else 0.0)
            stamp_t = max(stamp_t, 0.0)  # a data-clock stamp is never before the start
            msg = AcousticArrival(
                header=self._header(stamp_t, v.auv_id), receiver_id=v.auv_id, t_rx_local_s=theta, packet=pk
            )
            self._emit(stamp_t, v.auv_id, "acoustic", msg)
            if cfg.truth_at_leader_arrivals and pk.kind == "LEADER":
                self._emit(stamp_t, v.auv_id, "truth", self._truth_msg(v, stamp_t))
        if cfg.base_listener:
            b = np.asarray(cfg.base_position_ned_m)
            t = t_tx + float(np.linalg.norm(b - src)) / c
            msg = AcousticArrival(header=self._header(t, "base"), receiver_id="base", t_rx_local_s=t + 1.0, packet=pk)
            self._emit(t, "base", "acoustic", msg)
