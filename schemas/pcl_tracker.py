"""PCL tracker output (digest 003 §5.3): one scan report per processed scan with a report per track.

The inputs are :class:`schemas.radar.BistaticScan` and :class:`schemas.radar.BistaticConfigUpdate`.
Cartesian quantities are in the receiver-centred ENU frame named in ``header.frame_id`` (X east, Y north,
Z up); bistatic quantities are [r_b m, azimuth deg clockwise from north, elevation deg, v_b m/s]. Each track's
state and its bistatic image are :class:`~schemas.estimate.GaussianEstimate` blocks.
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

from pydantic import Field, model_validator

from .base import Message, StrictModel
from .estimate import CV_STATE, GaussianEstimate, Layout, block_field, check_blocks

TrackStatus = Literal["TENTATIVE", "CONFIRMED", "DROPPED"]
DropReason = Literal["K_misses", "MN_failed", "reset", "capacity"]
Probability = Annotated[float, Field(ge=0.0, le=1.0)]


#: a track's bistatic image (``PclTrackReport.bistatic``): z_b with the angles in degrees
BISTATIC = Layout(("r_b", "az", "el", "v_b"), ("m", "deg", "deg", "m/s"))


class PclTrackReport(StrictModel):
    """State of one track after a scan (or its final report in the scan it was dropped)."""

    track_id: int = Field(ge=1, description="monotonically increasing, never reused within a tracker instance")
    status: TrackStatus
    scan_id: int = Field(ge=0)
    t_s: float = Field(ge=0.0, description="scan time, s on the scenario clock (= header stamp)")
    estimate: GaussianEstimate = block_field(CV_STATE, "x_a(k|k), P_a(k|k) in the ENU frame (prediction if coasted)")
    bistatic: GaussianEstimate = block_field(
        BISTATIC, "UT image of the estimate through h_b (frame bistatic/<rx>/<tx>)"
    )
    associated_plot_id: str | None = Field(default=None, max_length=64, description="None: coasted this scan")
    nis: float | None = Field(default=None, ge=0.0, description="d^2 of the associated plot in the 4-D gate")
    n_plots_in_gate: int = Field(default=0, ge=0, description="plots of this scan inside the track's gate")
    coasted: bool = Field(default=False, description="no plot assigned this scan: output is the extrapolation")
    updated: bool = Field(default=False, description="the state was updated with a plot this scan")
    hits: int = Field(ge=0, description="associated plots, including the two initiating plots")
    consecutive_misses: int = Field(ge=0)
    age_scans: int = Field(ge=0, description="scans since creation")
    created_scan_id: int = Field(ge=0)
    confirm_progress: list[int] | None = Field(
        default=None, min_length=2, max_length=2, description="(hits in the M/N window, scans in it) while TENTATIVE"
    )
    filter_phase: Literal["ukf", "bkf"] = Field(default="ukf", description="bkf: in the comparison BKF phase")
    model_probabilities: list[Probability] | None = Field(
        default=None,
        min_length=1,
        max_length=8,
        description="IMM model probabilities mu_j in the order of the tracker's imm_q_m2s4 (None: one CV model)",
    )
    drop_reason: DropReason | None = None
    flags: list[str] = Field(default_factory=list, max_length=16, description="e.g. low_rb_hit, conversion_failed")

    @model_validator(mode="after")
    def _shapes(self) -> PclTrackReport:
        check_blocks(self)
        if (self.status == "DROPPED") != (self.drop_reason is not None):
            raise ValueError("drop_reason is set exactly when status is DROPPED")
        return self


class PclScanReport(Message):
    """Everything the PCL tracker knows after one scan of one receiver–illuminator pair."""

    schema_version: ClassVar[int] = 2

    receiver_id: str = Field(min_length=1, max_length=64)
    illuminator_id: str = Field(min_length=1, max_length=64)
    scan_id: int = Field(ge=0, description="scan processed (for trigger=config: the last processed scan)")
    trigger: Literal["scan", "config"] = Field(default="scan", description="config: geometry change reset")
    t_s: float = Field(ge=0.0, description="scan time, s on the scenario clock")
    tracks: list[PclTrackReport] = Field(default_factory=list, max_length=100_000)
    n_plots_in: int = Field(default=0, ge=0)
    n_plots_rejected: dict[str, int] = Field(default_factory=dict, description="reason -> count")
    n_plots_flagged: dict[str, int] = Field(default_factory=dict, description="kept but flagged: flag -> count")
    n_associated: int = Field(default=0, ge=0)
    n_initiated: int = Field(default=0, ge=0)
    n_candidates: int = Field(default=0, ge=0, description="first plots awaiting a partner after this scan")
    n_tentative: int = Field(default=0, ge=0)
    n_confirmed: int = Field(default=0, ge=0)
    n_dropped: int = Field(default=0, ge=0)
    n_coasting: int = Field(default=0, ge=0)
    gap_scans: int = Field(default=0, ge=0, description="missing scans before this one (counted as misses)")
    mean_nis: float | None = Field(default=None, ge=0.0, description="mean d^2 of associated plots (expected ~4)")
    gate_d2: float = Field(default=0.0, ge=0.0, description="association gate chi2_4(P_G)")
    n_cholesky_fallbacks: int = Field(default=0, ge=0, description="jitter or eigen-clip square roots this scan")
    n_sigma_clamped: int = Field(default=0, ge=0, description="plots whose UT sigma points needed r_b clamping")
    flags: list[str] = Field(default_factory=list, max_length=64)
