"""Outputs of the LBL estimator with no prior position and sparse beacons (digest 000, section 5.2).

``LblFix`` is published once per DR epoch. While two hypotheses are alive (status ``LAUNCH`` or
``AMBIGUOUS``) it carries no position (``valid`` is False, ``estimate`` is None) and lists both
hypotheses with their posterior probabilities; it never presents one of them as the fix.
``LblEvent`` reports launches, decisions, merges, buffer overflows, rejections and resets.

Frame: local horizontal frame with geographic axes, x = East, y = North, and depth positive down;
``estimate`` (a :class:`~schemas.estimate.GaussianEstimate`) has the components ``x, y, z`` =
``[x_east_m, y_north_m, depth_m]``; ``state`` is the filter's 6-state ``x, y, dc, dK, dU_north, dU_east``.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, model_validator

from .base import Message, Vec2
from .estimate import POSITION, GaussianEstimate, Layout, block_field, check_blocks
from .outputs import Hypothesis

LblStatus = Literal[
    "WAITING",  # no range received yet
    "BUFFERING",  # single-beacon epochs are being stored (i < 0)
    "LAUNCH",  # launch epoch (i = 0) with two hypotheses
    "UNIQUE",  # launch epoch with a single hypothesis (n_0 >= 3, favourable geometry)
    "AMBIGUOUS",  # two hypotheses alive, ratio between its bounds
    "RESOLVED",  # the epoch at which rule (6) accepted one hypothesis
    "MERGED",  # the epoch at which the two hypotheses were merged
    "TRACKING",  # one hypothesis, ranges used recently
    "DR_ONLY",  # one hypothesis, no range used for a while: dead reckoning only
]

LblEventKind = Literal[
    "launch",
    "launch_postponed",
    "decision",
    "merge",
    "buffer_overflow",
    "buffer_truncated",
    "rejected",
    "divergence",
    "filter_reset",
]


#: the filter state of ``LblFix.state`` (services/lbl_nav/models.py: IX .. IUE): position x (east), y (north);
#: sound-speed error dc; heading error dK (add to the measured heading); current errors dU_north, dU_east
LBL_STATE = Layout(("x", "y", "dc", "dK", "dU_north", "dU_east"), ("m", "m", "m/s", "rad", "m/s", "m/s"))


class LblFix(Message):
    """Per-epoch output of the LBL estimator: fix (once single-hypothesis) or the live hypotheses."""

    schema_version: ClassVar[int] = 2

    platform: str = Field(min_length=1, max_length=64)
    estimator: str = Field(default="lbl_nav", min_length=1, max_length=64)
    status: LblStatus
    valid: bool = Field(description="True only when one hypothesis remains: estimate may be used as a fix")
    estimate: GaussianEstimate | None = block_field(
        POSITION, "position x (east), y (north), z (depth); None unless valid", optional=True
    )
    hypotheses: list[Hypothesis] = Field(
        default_factory=list, max_length=2, description="every live hypothesis (id 1 or 2), probability from ratio"
    )
    log10_ratio: float | None = Field(
        default=None, description="log10 of the posterior ratio p(u=1|Y)/p(u=2|Y) (delta p 1/2); None if < 2 hyps"
    )
    log10_threshold: float = Field(gt=0.0, description="log10 of the decision threshold delta p max/min")
    accepted_hypothesis: int | None = Field(default=None, ge=1, le=2, description="u* once decided")
    hypothesis_source: Literal["resolved", "merged", "unique"] | None = None
    launch_stamp_ns: int | None = Field(default=None, ge=0, description="stamp of the launch epoch t_0")
    resolved_stamp_ns: int | None = Field(default=None, ge=0, description="stamp of the decision or merge")
    buffered_epochs: int = Field(default=0, ge=0, description="N: buffered epochs (before launch: so far)")
    processed_buffered: int = Field(default=0, ge=0, description="buffered epochs processed so far")
    saved_progress: float = Field(default=0.0, ge=0.0, le=1.0, description="processed / N (1 if N = 0)")
    catching_up: bool = Field(default=False, description="True while buffered epochs remain (s > -N)")
    state: GaussianEstimate | None = block_field(LBL_STATE, "the filter state; None unless valid", optional=True)
    sigma_dc_mps: float | None = Field(default=None, ge=0.0)
    sigma_dK_rad: float | None = Field(default=None, ge=0.0)  # noqa: N815
    sigma_dU_north_mps: float | None = Field(default=None, ge=0.0)  # noqa: N815
    sigma_dU_east_mps: float | None = Field(default=None, ge=0.0)  # noqa: N815
    ranges_used: int = Field(default=0, ge=0, description="current-epoch ranges used in the update")
    ranges_rejected: int = Field(default=0, ge=0, description="current-epoch ranges rejected by the gate")
    buffer_dropped: int = Field(default=0, ge=0, description="buffered epochs dropped (overflow, gaps) so far")
    degraded: bool = Field(default=False, description="dead-reckoning data missing for this epoch (held values)")

    @model_validator(mode="after")
    def _consistent(self) -> LblFix:
        if self.valid and self.estimate is None:
            raise ValueError("a valid LblFix needs its estimate")
        if not self.valid and self.estimate is not None:
            raise ValueError("an invalid LblFix must not carry a position (publish hypotheses instead)")
        check_blocks(self)
        if self.processed_buffered > self.buffered_epochs:
            raise ValueError("processed_buffered exceeds buffered_epochs")
        return self


class LblEvent(Message):
    """A notable event of the LBL estimator (launch, decision, merge, overflow, rejection, reset)."""

    platform: str = Field(min_length=1, max_length=64)
    estimator: str = Field(default="lbl_nav", min_length=1, max_length=64)
    kind: LblEventKind
    reason: str = Field(default="", max_length=64, description="short machine-readable reason code")
    detail: str = Field(default="", max_length=4096)
    hypothesis_id: int | None = Field(default=None, ge=1, le=2, description="u* of a decision")
    log10_ratio: float | None = None
    grid_nodes: int | None = Field(default=None, ge=0, description="L, launch grid nodes")
    cluster_sizes: list[int] = Field(default_factory=list, max_length=2)
    centres_m: list[Vec2] = Field(default_factory=list, max_length=2, description="[x_east_m, y_north_m] each")
    count: int = Field(default=1, ge=1, description="occurrences this event stands for")
