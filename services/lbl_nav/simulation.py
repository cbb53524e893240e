"""Pure truth and measurement simulation for the LBL estimator (digest 000, sections 1, 3.1, 4.2, 4.4).

Everything random comes from one ``numpy.random.Generator``; the output is the schemas' input messages
(stamps in ``header.stamp_ns``) in time order plus the truth arrays, so a player can replay it.

Error processes (section 1): constant sound-speed error dc ~ N(0, sigma_dc^2) with y = D + dc*D/c~ + delta + v;
common range error delta (white), independent range error v (white); white log noise (std sigma_dV over a 1-s
average); heading error dK and current errors dU_N, dU_E as stationary first-order Markov processes.
Conventions: true heading = measured heading + dK; true ground velocity = log velocity on the true heading
plus the known current U plus dU; the values at epoch t apply to the interval (t - dt, t].
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from schemas import Beacon, BeaconRange, BeaconTable, Current, Depth, Header, Heading, Message, SpeedLog, Truth
from shared.filters import gauss_markov

F64 = NDArray[np.float64]
NS = 1_000_000_000


@dataclass(frozen=True)
class SimBeacon:
    beacon_id: str
    x_east_m: float
    y_north_m: float
    depth_m: float


@dataclass(frozen=True)
class ScenarioSpec:
    """A fixed trajectory (t relative to the launch epoch t_0 = 0) and the error model of one Monte-Carlo set."""

    name: str
    beacons: tuple[SimBeacon, ...]
    #: (t_s, true heading deg clockwise from North), piecewise linear, constant outside; unwrapped degrees
    heading_knots: tuple[tuple[float, float], ...]
    launch_xy_m: tuple[float, float]
    t_start_s: float
    t_end_s: float
    speed_mps: float = 5.0
    v_starboard_mps: float = 0.0
    auv_depth_m: float = 30.0
    #: sinusoidal yaw added to the heading: amplitude (deg) and period (s); 0 amplitude: none
    yaw_amplitude_deg: float = 0.0
    yaw_period_s: float = 20.0
    reception_m: float = 1000.0
    pre_launch_beacons: tuple[str, ...] = ("B1",)
    launch_beacons: tuple[str, ...] = ("B1", "B2")
    known_current_ne_mps: tuple[float, float] = (0.0, 0.0)
    c_nominal_mps: float = 1500.0
    sigma_delta_m: float = 5.0
    sigma_v_m: float = 10.0
    sigma_dc_mps: float = 3.0
    sigma_dV_mps: float = 0.1  # noqa: N815
    sigma_dK_deg: float = 5.0  # noqa: N815
    sigma_dU_mps: float = 0.25  # noqa: N815
    tau_dK_s: float = 3600.0  # noqa: N815
    tau_dU_s: float = 3600.0  # noqa: N815
    dt_s: float = 1.0
    epoch0_s: float = 10_000.0
    ranges_as_travel_time: bool = False
    platform: str = "auv1"
    #: (t_s, +deg) extra heading excursions: triangular bumps (centre, half-width, peak deg)
    yaw_bumps: tuple[tuple[float, float, float], ...] = field(default=())

    def heading_deg(self, t: F64) -> F64:
        kt = np.array([k[0] for k in self.heading_knots])
        kv = np.array([k[1] for k in self.heading_knots])
        h = np.interp(t, kt, kv)
        if self.yaw_amplitude_deg:
            h = h + self.yaw_amplitude_deg * np.sin(2.0 * math.pi * t / self.yaw_period_s)
        for c, w, peak in self.yaw_bumps:
            h = h + peak * np.clip(1.0 - np.abs(t - c) / w, 0.0, None)
        return h


@dataclass(frozen=True)
class RecordedPath:
    """A recorded trajectory sampled at the epochs, replacing the synthetic motion (heading knots, speed, yaw).

    ``x_m``, ``y_m`` (east, north) and ``depth_m`` are the truth at each epoch, ``heading_rad`` the true heading
    there; ``v0_en_mps`` the ground velocity at the first epoch (its interval has no previous epoch)."""

    x_m: F64
    y_m: F64
    depth_m: F64
    heading_rad: F64
    v0_en_mps: tuple[float, float]


@dataclass
class SimRun:
    """One realisation: epoch times, truth, the error draws and the input messages."""

    spec: ScenarioSpec
    seed: int
    t_s: F64
    stamps_ns: NDArray[np.int64]
    x_m: F64
    y_m: F64
    heading_true_rad: F64
    dK_rad: F64  # noqa: N815
    dU_north_mps: F64  # noqa: N815
    dU_east_mps: F64  # noqa: N815
    dc_mps: float
    visible: dict[str, NDArray[np.bool_]]
    messages: list[Message]
    i0: int  # index of the launch epoch t = 0

    def index_of(self, stamp_ns: int) -> int:
        return round((stamp_ns - int(self.stamps_ns[0])) / (self.spec.dt_s * NS))

    def truth_messages(self) -> list[Truth]:
        sp = self.spec
        return [
            Truth(
                header=Header(stamp_ns=int(s), frame_id="local_en_depth", source="sim"),
                platform=sp.platform,
                position_m=[float(x), float(y), sp.auv_depth_m],
                attitude_rad=[float(k), 0.0, 0.0],
                extra={"dK_rad": float(dk), "dU_north_mps": float(un), "dU_east_mps": float(ue), "dc_mps": self.dc_mps},
            )
            for s, x, y, k, dk, un, ue in zip(
                self.stamps_ns,
                self.x_m,
                self.y_m,
                self.heading_true_rad,
                self.dK_rad,
                self.dU_north_mps,
                self.dU_east_mps,
                strict=True,
            )
        ]


def simulate(
    spec: ScenarioSpec,
    rng: np.random.Generator,
    seed: int = 0,
    header: Callable[[int, int], Header] | None = None,
    path: RecordedPath | None = None,
) -> SimRun:
    """Truth, error draws and the message stream of one run (draw order fixed, all beacons drawn every epoch).

    ``header(stamp_ns, epoch_index)`` makes the messages' headers (default: frame ``local_en_depth``, source
    ``sim``, seq = the epoch index).

    ``path``: a recorded trajectory as the truth (the spec's heading knots, speed, sway and yaw are not used).
    The ground velocity of the interval ending at epoch i is (p_i - p_(i-1)) / dt; the log measures it less the
    known current and dU, resolved on the true heading K_i (forward, starboard), plus its noise: so dead
    reckoning with the true heading and the noise-free log reproduces the recorded positions at every epoch
    exactly, as the synthetic truth does. The depth sensor and the slant ranges use the recorded depth."""
    dt = spec.dt_s
    n0 = round(-spec.t_start_s / dt)
    t = np.asarray((np.arange(round((spec.t_end_s - spec.t_start_s) / dt) + 1) - n0) * dt, dtype=np.float64)
    n = t.size
    nb = len(spec.beacons)
    # draws, in a fixed order
    dc = spec.sigma_dc_mps * float(rng.standard_normal())
    dK = gauss_markov.path(rng, n, math.radians(spec.sigma_dK_deg), spec.tau_dK_s, dt)
    dUN = gauss_markov.path(rng, n, spec.sigma_dU_mps, spec.tau_dU_s, dt)
    dUE = gauss_markov.path(rng, n, spec.sigma_dU_mps, spec.tau_dU_s, dt)
    log_noise = spec.sigma_dV_mps / math.sqrt(dt) * rng.standard_normal((n, 2))
    delta = spec.sigma_delta_m * rng.standard_normal(n)
    v = spec.sigma_v_m * rng.standard_normal((n, nb))
    # truth
    un, ue = spec.known_current_ne_mps
    if path is None:
        K = np.radians(spec.heading_deg(t))
        vE = spec.speed_mps * np.sin(K) + spec.v_starboard_mps * np.cos(K) + ue + dUE
        vN = spec.speed_mps * np.cos(K) - spec.v_starboard_mps * np.sin(K) + un + dUN
        x = np.empty(n)
        y = np.empty(n)
        x[n0], y[n0] = spec.launch_xy_m
        for i in range(n0 + 1, n):
            x[i] = x[i - 1] + vE[i] * dt
            y[i] = y[i - 1] + vN[i] * dt
        for i in range(n0, 0, -1):
            x[i - 1] = x[i] - vE[i] * dt
            y[i - 1] = y[i] - vN[i] * dt
        vf = spec.speed_mps + log_noise[:, 0]
        vs = spec.v_starboard_mps + log_noise[:, 1]
        depth: F64 | float = spec.auv_depth_m
    else:
        if path.x_m.size != n:
            raise ValueError(f"the recorded path has {path.x_m.size} epochs, the spec {n}")
        K, x, y, depth = path.heading_rad, path.x_m, path.y_m, path.depth_m
        vE = np.concatenate([[path.v0_en_mps[0]], np.diff(x) / dt])
        vN = np.concatenate([[path.v0_en_mps[1]], np.diff(y) / dt])
        wE, wN = vE - ue - dUE, vN - un - dUN  # through the water
        vf = wE * np.sin(K) + wN * np.cos(K) + log_noise[:, 0]
        vs = wE * np.cos(K) - wN * np.sin(K) + log_noise[:, 1]
    K_meas = K - dK
    stamps = np.round((spec.epoch0_s + t) * NS).astype(np.int64)
    # visibility and ranges
    visible: dict[str, NDArray[np.bool_]] = {}
    ranges = np.empty((n, nb))
    for j, b in enumerate(spec.beacons):
        hor = np.hypot(b.x_east_m - x, b.y_north_m - y)
        D = np.sqrt(hor**2 + (b.depth_m - depth) ** 2)
        ranges[:, j] = D + dc * D / spec.c_nominal_mps + delta + v[:, j]
        in_range = hor <= spec.reception_m
        vis = np.where(t < 0, in_range & (b.beacon_id in spec.pre_launch_beacons), in_range)
        vis[n0] = b.beacon_id in spec.launch_beacons
        visible[b.beacon_id] = vis
    msgs: list[Message] = []
    frame = "local_en_depth"
    h0 = Header(stamp_ns=int(stamps[0]), frame_id=frame, source="sim") if header is None else header(int(stamps[0]), 0)
    msgs.append(
        BeaconTable(
            header=h0,
            beacons=[
                Beacon(beacon_id=b.beacon_id, x_east_m=b.x_east_m, y_north_m=b.y_north_m, depth_m=b.depth_m)
                for b in spec.beacons
            ],
        )
    )
    msgs.append(Current(header=h0, u_north_mps=un, u_east_mps=ue))
    for i in range(n):
        h = (
            Header(stamp_ns=int(stamps[i]), frame_id=frame, source="sim", seq=i)
            if header is None
            else header(int(stamps[i]), i)
        )
        msgs.append(SpeedLog(header=h, v_forward_mps=float(vf[i]), v_starboard_mps=float(vs[i]), avg_interval_s=dt))
        msgs.append(Heading(header=h, heading_rad=float(math.remainder(K_meas[i], 2.0 * math.pi))))
        msgs.append(Depth(header=h, depth_m=spec.auv_depth_m if path is None else float(path.depth_m[i])))
        for j, b in enumerate(spec.beacons):
            if visible[b.beacon_id][i] and ranges[i, j] > 0.0:
                if spec.ranges_as_travel_time:
                    msgs.append(
                        BeaconRange(
                            header=h, beacon_id=b.beacon_id, travel_time_s=float(ranges[i, j] / spec.c_nominal_mps)
                        )
                    )
                else:
                    msgs.append(BeaconRange(header=h, beacon_id=b.beacon_id, range_m=float(ranges[i, j])))
    return SimRun(spec, seed, t, stamps, x, y, K, dK, dUN, dUE, dc, visible, msgs, n0)


# ---- the digest's scenarios -----------------------------------------------------------------------------------------
BEACONS_2 = (SimBeacon("B1", 0.0, 0.0, 100.0), SimBeacon("B2", 0.0, 1500.0, 100.0))
LAUNCH_XY = (450.0, 606.97)  # 1000 m horizontally from B2 (section 4.4)


def s1_spec() -> ScenarioSpec:
    """S1, simulation replica (section 4.4 reconstruction): turn before launch, 10 deg to the line, turn after."""
    return ScenarioSpec(
        name="S1",
        beacons=BEACONS_2,
        heading_knots=((-115.0, 80.0), (-100.0, -10.0), (150.0, -10.0), (165.0, 80.0)),
        launch_xy_m=LAUNCH_XY,
        t_start_s=-360.0,
        t_end_s=300.0,
    )


def s2_spec() -> ScenarioSpec:
    """S2, field-like replica: 4 m/s, 35 deg to the beacon line, mild yaw, sharper yaw about 10 s before launch,
    N = 97, no heading or current error (the filter is configured with sigma_dK = sigma_dU = 0)."""
    return ScenarioSpec(
        name="S2",
        beacons=BEACONS_2,
        heading_knots=((0.0, -35.0),),
        launch_xy_m=LAUNCH_XY,
        t_start_s=-97.0,
        t_end_s=90.0,
        speed_mps=4.0,
        yaw_amplitude_deg=2.0,
        yaw_period_s=25.0,
        yaw_bumps=((-10.0, 4.0, 20.0),),
        sigma_dK_deg=0.0,
        sigma_dU_mps=0.0,
    )


def s3_spec(angle_deg: float, t_end_s: float = 300.0) -> ScenarioSpec:
    """S3, geometry sweep: straight track at ``angle_deg`` to the beacon line (heading = angle, away from the line)."""
    return ScenarioSpec(
        name=f"S3-{angle_deg:g}",
        beacons=BEACONS_2,
        heading_knots=((0.0, angle_deg),),
        launch_xy_m=LAUNCH_XY,
        t_start_s=-360.0,
        t_end_s=t_end_s,
    )


def with_end(spec: ScenarioSpec, t_end_s: float) -> ScenarioSpec:
    return replace(spec, t_end_s=t_end_s)
