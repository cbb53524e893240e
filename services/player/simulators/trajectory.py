"""Piecewise constant-speed, constant-turn-rate, constant-climb-rate trajectories in an east/north/up frame.

A trajectory is a chain of segments. Within a segment the horizontal speed ``v`` (m/s), the turn rate
``omega`` (rad/s, + clockwise seen from above, i.e. to starboard) and the climb rate ``c`` (m/s, + up)
are constant, so the motion is an exact circular arc (or a straight line) with a linear altitude profile:

    heading(t) = h0 + omega * t                     (clockwise from north)
    east(t)    = e0 + v * t * sin(h0 + omega t / 2) * sinc(omega t / 2)
    north(t)   = n0 + v * t * cos(h0 + omega t / 2) * sinc(omega t / 2)
    up(t)      = u0 + c * t

Built from legs (duration, turn rate, climb rate, optional new speed) or from waypoints (turn at a fixed
rate towards the next waypoint, then fly straight to it). After the last segment the vehicle flies straight
and level at its last speed. Attitude is that of coordinated, zero-sideslip flight: pitch = atan(c / v)
(flight-path angle), roll = atan(v * omega / g).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from pydantic import AfterValidator, Field, model_validator

from .base import NS_PER_S, SimParams, TruthState

G_MPS2 = 9.80665
TWO_PI = 2.0 * math.pi


def _vec3(v: list[float]) -> list[float]:
    if len(v) != 3:
        raise ValueError(f"expected [east, north, up], 3 components, got {len(v)}")
    return v


Position3 = Annotated[list[float], AfterValidator(_vec3)]


class StartState(SimParams):
    """Initial state of the vehicle."""

    position_m: Position3 = Field(description="[east, north, up], m (an AUV at 30 m depth has up = -30)")
    heading_deg: float = Field(ge=-360.0, le=360.0, description="clockwise from north, deg")
    speed_mps: float = Field(ge=0.0, le=1000.0, description="horizontal speed, m/s")


class Leg(SimParams):
    """A leg flown for ``duration_s`` at constant speed, turn rate and climb rate."""

    duration_s: float = Field(gt=0.0, le=1e7, description="s")
    turn_rate_dps: float = Field(default=0.0, ge=-30.0, le=30.0, description="deg/s, + to starboard")
    climb_rate_mps: float = Field(default=0.0, ge=-100.0, le=100.0, description="m/s, + up (an AUV diving: < 0)")
    speed_mps: float | None = Field(default=None, ge=0.0, le=1000.0, description="new horizontal speed, m/s")


class Waypoint(SimParams):
    """A point to fly to (turn towards it at the route's turn rate, then straight)."""

    position_m: Position3 = Field(description="[east, north, up], m")
    speed_mps: float | None = Field(default=None, gt=0.0, le=1000.0, description="speed on the way here, m/s")


class Route(SimParams):
    """Where the vehicle goes: a start state and either legs or waypoints (not both)."""

    start: StartState
    legs: list[Leg] = Field(default_factory=list, max_length=10_000)
    waypoints: list[Waypoint] = Field(default_factory=list, max_length=10_000)
    turn_rate_dps: float = Field(default=3.0, gt=0.0, le=30.0, description="waypoint turns, deg/s")

    @model_validator(mode="after")
    def _legs_or_waypoints(self) -> Route:
        if self.legs and self.waypoints:
            raise ValueError("give either legs or waypoints, not both")
        if self.waypoints and self.start.speed_mps <= 0.0 and self.waypoints[0].speed_mps is None:
            raise ValueError("waypoints need a positive speed (start.speed_mps or the waypoint's speed_mps)")
        if self.waypoints:
            Trajectory.from_route(self)  # a waypoint inside the turn circle is a parameter error
        return self


@dataclass(frozen=True)
class Segment:
    """One constant-rate piece: start time (s), duration (s, may be inf), start position and rates."""

    t0_s: float
    duration_s: float
    position_m: tuple[float, float, float]
    heading_rad: float
    speed_mps: float
    turn_rate_rps: float
    climb_rate_mps: float

    def end(self) -> tuple[tuple[float, float, float], float]:
        """Position and heading at the end of the segment."""
        p, h = _advance(
            np.array(self.position_m),
            self.heading_rad,
            self.speed_mps,
            self.turn_rate_rps,
            self.climb_rate_mps,
            np.array([self.duration_s]),
        )
        return (float(p[0, 0]), float(p[0, 1]), float(p[0, 2])), float(h[0])


def _advance(
    p0: np.ndarray, h0: float, v: float, omega: float, climb: float, tau: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n, 3) and headings (n,) after flying ``tau`` seconds from (p0, h0)."""
    half = 0.5 * omega * tau
    mid = h0 + half
    along = v * tau * np.sinc(half / math.pi)  # np.sinc(x) = sin(pi x) / (pi x)
    pos = np.empty((tau.size, 3))
    pos[:, 0] = p0[0] + along * np.sin(mid)
    pos[:, 1] = p0[1] + along * np.cos(mid)
    pos[:, 2] = p0[2] + climb * tau
    return pos, h0 + omega * tau


@dataclass(frozen=True)
class States:
    """Truth at n instants (arrays). Positions, velocities and accelerations are [east, north, up]."""

    t_s: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray
    acceleration_mps2: np.ndarray
    heading_rad: np.ndarray  #: clockwise from north, wrapped to [0, 2 pi)
    pitch_rad: np.ndarray
    roll_rad: np.ndarray
    speed_mps: np.ndarray  #: horizontal
    turn_rate_rps: np.ndarray
    climb_rate_mps: np.ndarray


class Trajectory:
    """A chain of :class:`Segment` evaluated exactly at any time (vectorised)."""

    def __init__(self, segments: list[Segment]) -> None:
        if not segments or not math.isinf(segments[-1].duration_s):
            raise ValueError("the last segment must be open-ended")
        self.segments = segments
        self._t0 = np.array([s.t0_s for s in segments])

    @classmethod
    def from_route(cls, route: Route) -> Trajectory:
        start = route.start
        p = (float(start.position_m[0]), float(start.position_m[1]), float(start.position_m[2]))
        h = math.radians(start.heading_deg)
        if route.waypoints:
            return cls(_waypoint_segments(p, h, start.speed_mps, route.waypoints, math.radians(route.turn_rate_dps)))
        return cls(_leg_segments(p, h, start.speed_mps, route.legs))

    def states(self, t_s: np.ndarray) -> States:
        t = np.asarray(t_s, dtype=float)
        idx = np.clip(np.searchsorted(self._t0, t, side="right") - 1, 0, len(self.segments) - 1)
        pos = np.empty((t.size, 3))
        heading = np.empty(t.size)
        speed = np.empty(t.size)
        omega = np.empty(t.size)
        climb = np.empty(t.size)
        for i in np.unique(idx):
            seg = self.segments[int(i)]
            mask = idx == i
            p, h = _advance(
                np.array(seg.position_m),
                seg.heading_rad,
                seg.speed_mps,
                seg.turn_rate_rps,
                seg.climb_rate_mps,
                t[mask] - seg.t0_s,
            )
            pos[mask] = p
            heading[mask] = h
            speed[mask] = seg.speed_mps
            omega[mask] = seg.turn_rate_rps
            climb[mask] = seg.climb_rate_mps
        vel = np.stack([speed * np.sin(heading), speed * np.cos(heading), climb], axis=1)
        acc = np.stack([speed * omega * np.cos(heading), -speed * omega * np.sin(heading), np.zeros(t.size)], axis=1)
        return States(
            t_s=t,
            position_m=pos,
            velocity_mps=vel,
            acceleration_mps2=acc,
            heading_rad=np.mod(heading, TWO_PI),
            pitch_rad=np.arctan2(climb, speed),
            roll_rad=np.arctan(speed * omega / G_MPS2),
            speed_mps=speed,
            turn_rate_rps=omega,
            climb_rate_mps=climb,
        )

    def truth_at(self, stamps_ns: np.ndarray) -> TruthState:
        s = self.states(np.asarray(stamps_ns, dtype=np.int64) / NS_PER_S)
        return TruthState(s.position_m, s.velocity_mps, s.heading_rad, s.pitch_rad, s.roll_rad)


def _leg_segments(p: tuple[float, float, float], h: float, v: float, legs: list[Leg]) -> list[Segment]:
    segments: list[Segment] = []
    t = 0.0
    for leg in legs:
        v = v if leg.speed_mps is None else leg.speed_mps
        seg = Segment(t, leg.duration_s, p, h, v, math.radians(leg.turn_rate_dps), leg.climb_rate_mps)
        segments.append(seg)
        p, h = seg.end()
        t += leg.duration_s
    segments.append(Segment(t, math.inf, p, h, v, 0.0, 0.0))
    return segments


def _unit(bearing: float) -> np.ndarray:
    """Horizontal unit vector [east, north] of a bearing (clockwise from north)."""
    return np.array([math.sin(bearing), math.cos(bearing)])


def _turn_to(p: np.ndarray, h: float, radius: float, target: np.ndarray) -> list[float]:
    """Signed heading changes (rad; + starboard) after which a turn of ``radius`` points straight at ``target``.

    Exact tangent geometry: for a turn to starboard the centre is ``p + R u(h + 90 deg)`` and the tangent
    heading is ``beta + 90 deg - atan2(L, R)`` with ``beta`` the bearing centre -> target, ``d`` its
    distance and ``L = sqrt(d^2 - R^2)``; mirrored for a turn to port. Infeasible sides are left out.
    """
    options: list[float] = []
    for side in (1.0, -1.0):
        centre = p + radius * _unit(h + side * math.pi / 2)
        rel = target - centre
        d = float(np.hypot(rel[0], rel[1]))
        if d <= radius * (1.0 + 1e-9):
            continue
        beta = math.atan2(rel[0], rel[1])
        tangent = math.atan2(math.sqrt(d * d - radius * radius), radius)
        h_new = beta + side * (math.pi / 2 - tangent)
        change = (h_new - h) % TWO_PI if side > 0 else -((h - h_new) % TWO_PI)
        if abs(change) > TWO_PI - 1e-12:
            change = 0.0
        options.append(change)
    return options


def _waypoint_segments(
    p0: tuple[float, float, float], h: float, v: float, waypoints: list[Waypoint], turn_rate_rps: float
) -> list[Segment]:
    segments: list[Segment] = []
    t = 0.0
    p = p0
    for k, wp in enumerate(waypoints):
        v = v if wp.speed_mps is None else wp.speed_mps
        target = np.array(wp.position_m[:2], dtype=float)
        here = np.array(p[:2])
        if float(np.hypot(*(target - here))) < 1e-9:
            continue
        radius = v / turn_rate_rps
        options = _turn_to(here, h, radius, target)
        if not options:
            raise ValueError(
                f"waypoints[{k}] lies inside the turn circle (radius {radius:.1f} m at {v} m/s and "
                f"{math.degrees(turn_rate_rps)} deg/s): raise the turn rate or move the waypoint"
            )
        change = min(options, key=abs)
        if abs(change) > 1e-12:
            omega = math.copysign(turn_rate_rps, change)
            seg = Segment(t, abs(change) / turn_rate_rps, p, h, v, omega, 0.0)
            segments.append(seg)
            p, h = seg.end()
            t += seg.duration_s
        dist = float(np.hypot(*(target - np.array(p[:2]))))
        duration = dist / v
        climb = (float(wp.position_m[2]) - p[2]) / duration
        seg = Segment(t, duration, p, h, v, 0.0, climb)
        segments.append(seg)
        p, h = seg.end()
        t += duration
    segments.append(Segment(t, math.inf, p, h, v, 0.0, 0.0))
    return segments
