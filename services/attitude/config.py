"""Parameters of the attitude estimator (digest 004, §5.2) with the digest's defaults and units.

Tags in the descriptions follow the digest: [PAPER] stated in the paper, [RECON] rebuilt from the OCR,
[CHOICE] a default fixed by the digest because the paper is silent, [EXT] a service extension of the digest.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

RadarPreset = Literal["9S15", "Vostok3D", "19Zh6"]

#: measurement-error standard deviations of the paper's three radars (§3.2 table) [PAPER; digits as read]:
#: (sigma_r_m, sigma_az_deg, sigma_el_deg)
RADAR_PRESETS: dict[str, tuple[float, float, float]] = {
    "9S15": (225.0, 0.35, 0.3),
    "Vostok3D": (25.0, 0.5, 0.1),
    "19Zh6": (250.0, 0.4, 1.0),
}


class MeasurementSigmas(BaseModel):
    """One-sigma errors of a plot's range (m), azimuth (deg) and elevation (deg)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    sigma_r_m: float = Field(gt=0.0)
    sigma_az_deg: float = Field(gt=0.0)
    sigma_el_deg: float = Field(gt=0.0)

    @classmethod
    def preset(cls, radar: RadarPreset) -> MeasurementSigmas:
        r, az, el = RADAR_PRESETS[radar]
        return cls(sigma_r_m=r, sigma_az_deg=az, sigma_el_deg=el)


class AttitudeConfig(BaseModel):
    """Configuration of one :class:`~services.attitude.core.AttitudeCore` (one radar site, many targets)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    # --- radar site -----------------------------------------------------------------------------
    site_id: str | None = Field(
        default=None, description="accept plots of this site only; None accepts any site (state keyed per site)"
    )
    radar: RadarPreset | None = Field(
        default="9S15", description="named sigma preset of §3.2 [PAPER]; explicit sigma_* fields override it"
    )
    sigma_r_m: float | None = Field(default=None, gt=0.0, description="range error std, m (overrides preset)")
    sigma_az_deg: float | None = Field(default=None, gt=0.0, description="azimuth error std, deg")
    sigma_el_deg: float | None = Field(default=None, gt=0.0, description="elevation error std, deg")
    scan_period_s: float = Field(default=5.0, gt=0.0, description="nominal scan period T, s [PAPER: 5 s]")

    # --- filter -----------------------------------------------------------------------------------
    fsf_n: int = Field(default=3, ge=3, le=50, description="plots in the finite-sample-filter start [PAPER: 3]")
    sigma_jerk_mps3: tuple[float, float, float] = Field(
        default=(0.03, 0.03, 0.03),
        description="random-jerk std per axis (x=N, y=Up, z=E), m/s^3; D = sigma^2 [CHOICE; paper gives no value]",
    )
    g_mps2: float = Field(default=9.81, gt=0.0, description="gravity in eq. (4), m/s^2 (the OCR reads 9.82)")
    nis_gate: float | None = Field(
        default=21.1, gt=0.0, description="innovation gate, chi2(3) 99.99 % quantile [EXT]; None disables it"
    )
    nis_reset_count: int = Field(default=3, ge=1, description="consecutive gate failures that reset a track [EXT]")
    fsf_min_spread_scans: float = Field(
        default=0.5, ge=0.0, description="FSF waits until t_n - t_1 >= this x T (§5.6) [CHOICE]"
    )
    fsf_max_cond: float = Field(default=1e12, gt=1.0, description="FSF waits while cond(H_n) exceeds this (§5.6)")

    # --- angle block ------------------------------------------------------------------------------
    los_x: Literal["radar_to_target", "target_to_radar"] = Field(
        default="radar_to_target", description="direction of the LOS frame's x axis (§1.2) [CHOICE]"
    )
    los_dir_source: Literal["filtered", "measured"] = Field(
        default="filtered", description="beta, eps of A_LE from the filtered position or the current plot [CHOICE]"
    )
    roll_mode: Literal["arctan", "atan2"] = Field(
        default="arctan", description="eq. (4) roll: principal-value arctan (paper) or full-circle atan2"
    )
    gamma_los_form: Literal["paper", "euler"] = Field(
        default="paper", description="which roll goes to gamma_los_deg; gamma_los_euler_deg is always emitted"
    )
    jacobian: Literal["analytic", "central_difference"] = Field(
        default="analytic",
        description="angle Jacobian: exact chain rule, or central differences with jacobian_steps (§2.5)",
    )
    jacobian_steps: tuple[float, float, float] = Field(
        default=(1.0, 0.1, 0.01),
        description="central-difference steps for position (m), velocity (m/s), acceleration (m/s^2) (§2.5)",
    )

    # --- validity and status (§5.5, §5.6) ----------------------------------------------------------
    v_min_mps: float = Field(default=10.0, ge=0.0, description="horizontal speed below which heading is undefined")
    heading_sigma_factor: float = Field(
        default=3.0, ge=0.0, description="heading undefined while V_h < factor x sigma(V_h); 0 disables the rule"
    )
    min_normal_force_g: float = Field(
        default=0.1, ge=0.0, description="roll undefined while the normal specific force is below this, g"
    )
    valid_sigma_deg: float = Field(default=5.0, gt=0.0, description="VALID needs all three LOS sigmas below, deg")
    min_updates_valid: int = Field(default=10, ge=1, description="VALID needs at least this many plots in the state")
    linearisation_sigma_max_deg: float = Field(
        default=30.0, gt=0.0, description="LINEARISATION_INVALID when any angle sigma exceeds this, deg"
    )
    sigma_cap_deg: float = Field(default=180.0, gt=0.0, description="reported sigmas are capped here when invalid")
    max_gap_scans: int = Field(default=3, ge=1, description="gap (in T) predicted over; longer gaps reset")
    reset_gap_scans: float = Field(default=3.5, gt=0.0, description="reset when t - t_last > this x T (§5.2)")
    coast_output: bool = Field(default=False, description="emit COASTING estimates at missed scan times")
    coast_after_scans: float = Field(default=1.5, gt=0.0, description="a scan counts as missed after this x T")
    idle_timeout_s: float = Field(default=60.0, gt=0.0, description="targets idle this long (data time) are evicted")
    housekeeping_interval_s: float = Field(
        default=1.0, gt=0.0, description="eviction/coasting sweep period on the data clock, s"
    )
    duplicate_time_s: float = Field(default=1e-3, ge=0.0, description="plots closer than this to the last are dropped")

    # --- outputs ------------------------------------------------------------------------------------
    emit_init: bool = Field(default=True, description="emit INIT/RESET messages (angles null) before the FSF start")
    raw_output: bool = Field(
        default=False, description="attach the raw sliding-FSF angles (§2.6) to every output (diagnostic)"
    )
    validate_covariances: bool = Field(
        default=True,
        description="run the schema's symmetric-PSD check on the output covariances; False skips only that check "
        "(P is Cholesky-checked and J P J^T symmetrised by the core), every other field is still validated",
    )
    frame_id_prefix: str = Field(default="radar_nue/", description="output frame_id = prefix + site_id")
    source: str = Field(default="attitude", description="header.source of the outputs")

    @model_validator(mode="after")
    def _sigmas_resolvable(self) -> AttitudeConfig:
        if self.radar is None and None in (self.sigma_r_m, self.sigma_az_deg, self.sigma_el_deg):
            raise ValueError("give a radar preset or all three sigma_* values")
        if self.reset_gap_scans < self.coast_after_scans:
            raise ValueError("reset_gap_scans must not be shorter than coast_after_scans")
        if any(not math.isfinite(s) or s < 0.0 for s in self.sigma_jerk_mps3):
            raise ValueError("sigma_jerk_mps3 must be finite and >= 0")
        if any(not math.isfinite(s) or s <= 0.0 for s in self.jacobian_steps):
            raise ValueError("jacobian_steps must be finite and > 0")
        return self

    def measurement_sigmas(self) -> MeasurementSigmas:
        """The radar's default sigmas: preset values overridden by any explicit sigma_* field."""
        base = RADAR_PRESETS[self.radar] if self.radar is not None else (math.nan, math.nan, math.nan)
        return MeasurementSigmas(
            sigma_r_m=self.sigma_r_m if self.sigma_r_m is not None else base[0],
            sigma_az_deg=self.sigma_az_deg if self.sigma_az_deg is not None else base[1],
            sigma_el_deg=self.sigma_el_deg if self.sigma_el_deg is not None else base[2],
        )

    def jerk_variances(self) -> tuple[float, float, float]:
        """D_x, D_y, D_z of the random-manoeuvre matrix, m^2/s^6."""
        sx, sy, sz = self.sigma_jerk_mps3
        return (sx * sx, sy * sy, sz * sz)
