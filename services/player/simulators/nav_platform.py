"""``nav_platform``: a vehicle (AUV or aircraft) on a route, publishing truth and navigation sensors.

Keys: ``fixstream/truth/<platform>`` (:class:`schemas.Truth` at ``truth_rate_hz``) and
``fixstream/sensor/<platform>/<type>/<id>`` per sensor. Positions are [east, north, up] in the
scenario's ``frame_id``; the trajectory is registered in the scenario context under ``platform`` so later
simulators can use it.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterator
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from schemas import Truth
from shared import keys

from .base import NS_PER_S, Event, ScenarioContext, child_rng, sample_stamps_ns
from .columns import ColumnStream
from .registry import register
from .sensors import DepthParams, KeyChunk, Sensor, SensorStream
from .trajectory import Route, Trajectory


class NavPlatformParams(Route):
    """Parameters of ``nav_platform`` (the route fields ``start``, ``legs``/``waypoints``, ``turn_rate_dps`` too)."""

    platform: KeyChunk = Field(description="platform id used in the keys")
    vehicle: Literal["auv", "aircraft"] = Field(default="auv", description="auv: depth sensors allowed")
    truth_rate_hz: float = Field(default=10.0, gt=0.0, le=1000.0, description="Truth sample rate, Hz")
    sensors: list[Sensor] = Field(default_factory=list, max_length=256)

    @model_validator(mode="after")
    def _sensors_fit(self) -> NavPlatformParams:
        seen: set[tuple[str, str]] = set()
        for i, s in enumerate(self.sensors):
            if (s.type, s.id) in seen:
                raise ValueError(f"sensors[{i}]: a {s.type} sensor with id {s.id!r} is already defined")
            seen.add((s.type, s.id))
            if isinstance(s, DepthParams) and self.vehicle != "auv":
                raise ValueError(f"sensors[{i}]: a depth sensor needs vehicle: auv")
        return self


@register("nav_platform")
class NavPlatform:
    """Truth and sensor streams of one vehicle."""

    Params = NavPlatformParams

    def __init__(self, params: NavPlatformParams, rng: np.random.Generator, context: ScenarioContext) -> None:
        self.params = params
        self.context = context
        self.trajectory = Trajectory.from_route(params)
        context.register_platform(params.platform, self.trajectory)
        self.truth_key = keys.truth(params.platform)
        self.sensors = [
            SensorStream(s, params.platform, self.trajectory, child_rng(rng, f"{s.type}/{s.id}"), context)
            for s in params.sensors
        ]

    def truth_stream(self) -> ColumnStream:
        """:class:`schemas.Truth` at ``truth_rate_hz`` as columns."""
        stamps = sample_stamps_ns(self.params.truth_rate_hz, self.context.duration_ns, budget=(self.context, "truth"))
        st = self.trajectory.states(stamps / NS_PER_S)
        columns = {
            "position_m": st.position_m,
            "velocity_mps": st.velocity_mps,
            "acceleration_mps2": st.acceleration_mps2,
            "attitude_rad": np.stack([st.heading_rad, st.pitch_rad, st.roll_rad], axis=1),
            "extra.speed_mps": st.speed_mps,
            "extra.turn_rate_rps": st.turn_rate_rps,
            "extra.climb_rate_mps": st.climb_rate_mps,
            "extra.depth_m": -st.position_m[:, 2],
        }
        return ColumnStream(
            self.truth_key, Truth, self.context.frame_id, stamps, columns, {"platform": self.params.platform}
        )

    def column_streams(self) -> list[ColumnStream]:
        """Truth, then each sensor in file order: :meth:`events` is their stamp-ordered merge, ties in this order."""
        return [self.truth_stream(), *(s.column_stream() for s in self.sensors)]

    def events(self) -> Iterator[Event]:
        return heapq.merge(*(c.events() for c in self.column_streams()), key=lambda e: e.stamp_ns)
