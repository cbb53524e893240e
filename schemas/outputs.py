"""Estimator outputs: position fixes with covariance and tracks.

These are the common shapes; an estimator whose output carries more (hypotheses, verdicts, angles)
publishes a model of its own. Every mean with its covariance is a :class:`~schemas.estimate.GaussianEstimate`
block (``estimate``), so a reader converts any fix or track the same way.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, model_validator

from .base import Message, StrictModel
from .estimate import CV_STATE, POSITION, VELOCITY, GaussianEstimate, block_field, check_blocks


class Hypothesis(StrictModel):
    """One live hypothesis of a multi-hypothesis estimator."""

    hypothesis_id: int = Field(ge=0)
    estimate: GaussianEstimate = block_field(POSITION, "its position")
    probability: float = Field(ge=0.0, le=1.0)

    @model_validator(mode="after")
    def _shapes(self) -> Hypothesis:
        check_blocks(self)
        return self


class Fix(Message):
    """A position fix of one platform by one estimator, in ``header.frame_id``."""

    schema_version: ClassVar[int] = 2

    platform: str = Field(min_length=1, max_length=64)
    estimator: str = Field(min_length=1, max_length=64)
    status: str = Field(min_length=1, max_length=64, description="estimator-specific status word")
    valid: bool = Field(description="True if the position may be used as a fix")
    estimate: GaussianEstimate = block_field(POSITION, "the position")
    velocity: GaussianEstimate | None = block_field(VELOCITY, "the velocity", optional=True)
    hypotheses: list[Hypothesis] = Field(default_factory=list, max_length=64)

    @model_validator(mode="after")
    def _shapes(self) -> Fix:
        check_blocks(self)
        return self


class Track(Message):
    """A tracked target's Cartesian state [x, y, z, vx, vy, vz] and its 6x6 covariance."""

    schema_version: ClassVar[int] = 2

    tracker: str = Field(min_length=1, max_length=64)
    track_id: int = Field(ge=0)
    status: Literal["TENTATIVE", "CONFIRMED", "DROPPED"]
    estimate: GaussianEstimate = block_field(CV_STATE, "the Cartesian state")
    drop_reason: str | None = Field(default=None, max_length=64)

    @model_validator(mode="after")
    def _shapes(self) -> Track:
        check_blocks(self)
        return self
