"""Ground truth published by the scenario player on its own keys, and scenario markers."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from .base import MAX_SEQ, Message, Vec3


class Truth(Message):
    """True kinematic state of a platform (vehicle, aircraft, target) in ``header.frame_id``."""

    platform: str = Field(min_length=1, max_length=64)
    position_m: Vec3
    velocity_mps: Vec3 | None = None
    acceleration_mps2: Vec3 | None = None
    attitude_rad: Vec3 | None = Field(default=None, description="[heading, pitch, roll], rad")
    extra: dict[str, float] = Field(default_factory=dict, max_length=64, description="simulator-specific true values")


class ScenarioMarker(Message):
    """Start and end of a scenario run; the end marker carries the published count per key."""

    event: Literal["start", "end"]
    scenario: str = Field(max_length=256)
    seed: int = Field(ge=0, le=2**63 - 1)
    published: dict[str, Annotated[int, Field(ge=0, le=MAX_SEQ)]] = Field(
        default_factory=dict, max_length=65_536, description="messages published per key (seq 0 to n - 1 of its source)"
    )
