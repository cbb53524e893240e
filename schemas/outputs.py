"""Estimator outputs: position fixes with covariance and tracks.

These are the common shapes; an estimator whose output carries more (hypotheses, verdicts, angles)
publishes a model of its own that keeps these field names for the shared parts.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from .base import Covariance, Message, StrictModel, Vec3


class Hypothesis(StrictModel):
    """One live hypothesis of a multi-hypothesis estimator."""

    hypothesis_id: int = Field(ge=0)
    position_m: Vec3
    position_cov_m2: Covariance
    probability: float = Field(ge=0.0, le=1.0)


class Fix(Message):
    """A position fix of one platform by one estimator, in ``header.frame_id``."""

    platform: str = Field(min_length=1, max_length=64)
    estimator: str = Field(min_length=1, max_length=64)
    status: str = Field(min_length=1, max_length=64, description="estimator-specific status word")
    valid: bool = Field(description="True if the position may be used as a fix")
    position_m: Vec3
    position_cov_m2: Covariance = Field(description="3x3, m^2")
    velocity_mps: Vec3 | None = None
    velocity_cov_m2s2: Covariance | None = None
    hypotheses: list[Hypothesis] = Field(default_factory=list, max_length=64)

    @model_validator(mode="after")
    def _shapes(self) -> Fix:
        if len(self.position_cov_m2) != 3:
            raise ValueError("position_cov_m2 must be 3x3")
        if self.velocity_cov_m2s2 is not None and len(self.velocity_cov_m2s2) != 3:
            raise ValueError("velocity_cov_m2s2 must be 3x3")
        return self


class Track(Message):
    """A tracked target's Cartesian state [x, y, z, vx, vy, vz] and its 6x6 covariance."""

    tracker: str = Field(min_length=1, max_length=64)
    track_id: int = Field(ge=0)
    status: Literal["TENTATIVE", "CONFIRMED", "DROPPED"]
    state: list[float] = Field(min_length=6, max_length=6, description="m and m/s")
    covariance: Covariance = Field(description="6x6, SI units")
    drop_reason: str | None = Field(default=None, max_length=64)

    @model_validator(mode="after")
    def _shapes(self) -> Track:
        if len(self.covariance) != 6:
            raise ValueError("covariance must be 6x6")
        return self
