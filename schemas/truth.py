"""Ground truth published by the scenario player on its own keys, and scenario markers."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from .base import Message, Vec3


class Truth(Message):
    """True kinematic state of a platform (vehicle, aircraft, target) in ``header.frame_id``."""

    platform: str = Field(min_length=1, max_length=64)
    position_m: Vec3
    velocity_mps: Vec3 | None = None
    acceleration_mps2: Vec3 | None = None
    attitude_rad: Vec3 | None = Field(default=None, description="[heading, pitch, roll], rad")
    extra: dict[str, float] = Field(default_factory=dict, description="simulator-specific true values")


class ScenarioMarker(Message):
    """Start and end of a scenario run; the end marker carries the published count per key."""

    event: Literal["start", "end"]
    scenario: str = Field(max_length=256)
    seed: int
    published: dict[str, int] = Field(default_factory=dict, description="messages published per key")
