"""Parameters of the LBL estimator (digest 000, section 5.5) with the paper's defaults and units.

Tags in the field descriptions: [P] paper value, [R] digest reconstruction, [D] digest design default,
[IMPL] engineering addition of the digest (section 5.4) or of this implementation.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas import Beacon

#: field values each preset sets unless they are given explicitly
PRESETS: dict[str, dict[str, object]] = {
    # the paper's rule (6) on the EKF's accumulated ratio
    "paper": {"decision_statistic": "ekf", "robust_prior_scale": 1.0},
    # rule (6) on the exact evidence of the whole record, robust to the width of the error-state priors
    "honest": {"decision_statistic": "exact", "robust_prior_scale": 2.0},
}


class LblNavConfig(BaseModel):
    """Configuration of one core instance (one vehicle)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    platform: str = Field(default="auv1", min_length=1, max_length=64, description="vehicle name in the outputs")
    frame_id: str = Field(default="local_en_depth", description="frame of the outputs (x East, y North, depth)")
    beacons: list[Beacon] = Field(default_factory=list, description="beacon table; a BeaconTable message replaces it")

    # --- epoch grid -------------------------------------------------------------------------------------------
    dt_s: float = Field(default=1.0, gt=0.0, le=60.0, description="[P] epoch period Delta t, s")
    epoch_offset_s: float = Field(default=0.0, ge=0.0, description="[IMPL] grid epochs at offset + k*dt, s")
    epoch_tolerance_s: float = Field(
        default=0.05, ge=0.0, description="[IMPL] max |stamp - epoch| of a range attached to an epoch, s"
    )
    reorder_latency_s: float = Field(
        default=0.25, ge=0.0, description="[IMPL] an epoch closes when data later than epoch + latency arrives, s"
    )

    # --- range measurement model (1) ---------------------------------------------------------------------------
    c_nominal_mps: float = Field(default=1500.0, gt=1000.0, lt=2000.0, description="[D] a priori sound speed c~")
    sigma_delta_m: float = Field(default=5.0, ge=0.0, description="[P] common (synchronisation) range error std, m")
    sigma_v_m: float = Field(default=10.0, gt=0.0, description="[P] independent range error std, m")
    sigma_dc_mps: float = Field(default=3.0, gt=0.0, description="[P] sound-speed error std (constant), m/s")

    # --- dead-reckoning error model (2) ------------------------------------------------------------------------
    sigma_dV_mps: float = Field(default=0.1, ge=0.0, description="[P] log white noise std over a 1-s average, m/s")  # noqa: N815
    sigma_dK_rad: float = Field(default=math.radians(5.0), ge=0.0, description="[P] heading error std (Markov), rad")  # noqa: N815
    sigma_dU_mps: float = Field(default=0.25, ge=0.0, description="[P] current error std per component, m/s")  # noqa: N815
    tau_dK_s: float = Field(default=3600.0, gt=0.0, description="[P] heading error correlation interval, s")  # noqa: N815
    tau_dU_s: float = Field(default=3600.0, gt=0.0, description="[P] current error correlation interval, s")  # noqa: N815
    sigma_w_form: Literal["sqrt", "linear"] = Field(
        default="sqrt", description="[R] sigma_w = sigma_dV*sqrt(dt*1s) ('sqrt') or sigma_dV*dt ('linear', as printed)"
    )
    markov_form: Literal["exact", "euler"] = Field(
        default="exact", description="[R] AR(1) with a=exp(-dt/tau) ('exact') or a=1-dt/tau ('euler')"
    )
    heading_linearisation: Literal["zero", "estimate"] = Field(
        default="zero",
        description="[IMPL] linearise the dK terms of (2)/(U6) about dK = 0 as printed ('zero') or about the "
        "current dK estimate ('estimate', removes the second-order error of large heading errors)",
    )
    ekf_iterations: int = Field(
        default=1, ge=1, le=20, description="[IMPL] measurement-update iterations: 1 = plain EKF (paper), >1 = iterated"
    )
    second_order: bool = Field(
        default=False,
        description="[IMPL] Gaussian second-order range correction (1/2 tr(Hess P) bias and variance); False: EKF",
    )
    known_current_north_mps: float = Field(default=0.0, description="[IMPL] U^N used until a Current message")
    known_current_east_mps: float = Field(default=0.0, description="[IMPL] U^E used until a Current message")

    # --- launch (2.1, 2.2) ----------------------------------------------------------------------------------------
    D_max_m: float = Field(default=1500.0, gt=0.0, description="[P] max possible horizontal reception range, m")
    dx_nom_m: float = Field(default=300.0, gt=0.0, description="[P] nominal grid step delta x~, m")
    grid_even: bool = Field(default=True, description="[R] round L up to even so no node lies on the baseline")
    grid_half_width_m: float | None = Field(
        default=None, gt=0.0, description="[R] grid covers xb -/+ this (Delta x = 2*this); None: D_max"
    )
    gn_iter: int = Field(default=5, ge=1, le=100, description="[P] Gauss-Newton iterations per grid node")
    gn_residual_prob: float = Field(
        default=0.9999, gt=0.0, lt=1.0, description="[IMPL] drop GN nodes whose weighted residual exceeds this chi2"
    )
    cluster_min_gap_m: float = Field(
        default=1.0, ge=0.0, description="[IMPL] largest-gap below this: one cluster, single hypothesis"
    )
    collinear_tol_m: float = Field(
        default=1.0, ge=0.0, description="[IMPL] n0>=3: beacons collinear if smallest principal spread below this, m"
    )
    ellipse_axis_max_m: float = Field(
        default=50.0, gt=0.0, description="[R/IMPL] n0>=3: two hypotheses if the error-ellipse major semi-axis exceeds"
    )
    launch_evidence_multi: bool = Field(
        default=True, description="[IMPL] n0>=3 two-hypothesis launch: seed A, B with each candidate's fit of Y_0"
    )

    # --- buffered processing (2.4) --------------------------------------------------------------------------------
    use_buffered: bool = Field(default=True, description="False: drop the buffer at launch (N = 0), 'without'")
    dN0: int = Field(default=0, ge=0, description="[P] buffered epochs processed at launch, Delta N_0")  # noqa: N815
    dN: int = Field(default=10, ge=1, description="[P] buffered epochs processed per later epoch, Delta N")  # noqa: N815
    N_max: int = Field(default=360, ge=0, description="[D] buffer cap N_max (360 paper sim, 97 field)")

    # --- decision (2.5) -------------------------------------------------------------------------------------------
    preset: Literal["honest", "paper"] = Field(
        default="honest",
        description="[IMPL] decision rule: 'paper' = rule (6) on the EKF ratio; 'honest' = rule (6) on the exact "
        "evidence of the whole record, robust to the error-state priors (see decision.py); sets the fields below "
        "unless they are given",
    )
    decision_statistic: Literal["ekf", "exact"] = Field(
        default="exact", description="[IMPL] ln dp compared with the threshold: the EKF's (paper) or the exact one"
    )
    robust_prior_scale: float = Field(
        default=2.0,
        ge=1.0,
        le=100.0,
        description="[IMPL] exact rule: the decision must also hold with sigma_dK, sigma_dU times this (1: no check)",
    )
    exact_trigger_decades: float = Field(
        default=1.0, ge=0.0, le=100.0, description="[IMPL] evaluate the exact ratio when the EKF's is this close"
    )
    exact_recheck_epochs: int = Field(
        default=5, ge=1, description="[IMPL] epochs between two exact evaluations while the EKF ratio stays close"
    )
    ratio_threshold: float = Field(default=1e4, gt=1.0, description="[P] delta p max/min")
    r_merge_m: float = Field(default=20.0, ge=0.0, description="[D] merge radius r (not given by the paper), m")

    # --- bad input (5.4) ------------------------------------------------------------------------------------------
    v_max_mps: float = Field(default=8.0, gt=0.0, description="[IMPL] max vehicle speed for the range-rate gate")
    gate_sigma_k: float = Field(default=3.0, gt=0.0, description="[IMPL] k of the k*sigma physical/range-rate gates")
    gate_prob: float = Field(
        default=0.9999, gt=0.0, lt=1.0, description="[IMPL] chi2 quantile of the post-launch innovation gate"
    )
    dr_hold_max_s: float = Field(default=5.0, ge=0.0, description="[IMPL] hold DR values over gaps up to this, s")
    dr_gap_inflation_per_s: float = Field(
        default=1.0, ge=0.0, description="[IMPL] sigma_w scaled by 1 + this*gap over a DR gap, 1/s"
    )
    divergence_epochs: int = Field(
        default=10, ge=1, description="[IMPL] consecutive all-rejected range epochs that trigger a re-launch"
    )
    dr_only_after_s: float = Field(default=30.0, ge=0.0, description="[IMPL] DR_ONLY when no range used for this, s")
    max_epochs_per_step: int = Field(
        default=1_000,
        ge=1,
        description="[IMPL] a stamp jump beyond this many epochs resets the estimator (each epoch of a jump is closed "
        "and published: 100,000 once cost 15 s in one message)",
    )
    sigma_depth_m: float = Field(
        default=0.0, ge=0.0, description="[IMPL] depth std reported in the fix's position covariance"
    )
    validate_outputs: bool = Field(
        default=True, description="[IMPL] False: build outputs without pydantic validation (Monte-Carlo speed only)"
    )

    @model_validator(mode="before")
    @classmethod
    def _preset(cls, data: object) -> object:
        """Fill the preset's values of the fields that are not given explicitly."""
        if isinstance(data, dict):
            name = data.get("preset", "honest")
            if isinstance(name, str) and name in PRESETS:
                data = {**PRESETS[name], **data}
        return data

    @model_validator(mode="after")
    def _check(self) -> LblNavConfig:
        ids = [b.beacon_id for b in self.beacons]
        if len(ids) != len(set(ids)):
            raise ValueError("beacon ids must be unique")
        if self.epoch_tolerance_s > 0.5 * self.dt_s:
            raise ValueError("epoch_tolerance_s must not exceed dt_s / 2")
        if self.reorder_latency_s < self.epoch_tolerance_s:
            raise ValueError("reorder_latency_s must be at least epoch_tolerance_s")
        return self

    # derived -------------------------------------------------------------------------------------------------------
    @property
    def sigma_range_m(self) -> float:
        """Std of a scalar range, sqrt(sigma_delta^2 + sigma_v^2), m."""
        return math.hypot(self.sigma_delta_m, self.sigma_v_m)

    @property
    def ln_threshold(self) -> float:
        return math.log(self.ratio_threshold)

    def grid_nodes(self) -> int:
        """L of (U2): ceil(Delta x / delta x~) + 1, rounded up to even if ``grid_even``."""
        width = 2.0 * (self.grid_half_width_m if self.grid_half_width_m is not None else self.D_max_m)
        L = math.ceil(width / self.dx_nom_m - 1e-12) + 1
        if self.grid_even and L % 2 == 1:
            L += 1
        return max(L, 2)
