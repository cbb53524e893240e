"""Configuration of one PCL tracker instance (one receiver–illuminator pair), mirroring digest 003 §5.1.

Tags in the descriptions: [P] paper, [R] reconstructed, [D] design default of the digest, [S] derived by the
digest's reference simulation, [E] added by this implementation (not in the digest).
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy.stats import chi2

from .geometry import baseline

SPEED_OF_LIGHT_MPS = 299_792_458.0


class _Cfg(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class GeometryConfig(_Cfg):
    receiver_id: str = Field(default="rx1", min_length=1, max_length=64)
    illuminator_id: str = Field(default="tx-fm-98.1", min_length=1, max_length=64)
    tx_position_enu_m: tuple[float, float, float] = Field(
        default=(8000.0, 0.0, 300.0), description="[P] transmitter relative to the receiver (E, N, U), m"
    )
    wavelength_m: float | None = Field(default=3.06, gt=0.0, description="[D] illuminator wavelength, m (Doppler)")
    doppler_sign: Literal[-1, 1] = Field(default=-1, description="[R] v_b = doppler_sign * wavelength * f_d")
    c_mps: float = Field(default=SPEED_OF_LIGHT_MPS, gt=0.0, description="speed of light for delay_s -> r_b, m/s")
    frame_id: str = Field(default="pcl_enu", max_length=128, description="[E] frame_id of the output messages")

    @property
    def L_m(self) -> float:
        return baseline(self.tx_position_enu_m)


class MeasurementDefaults(_Cfg):
    """Sigmas used when a plot has none or an invalid one (digest §5.6). Paper values [P]."""

    sigma_rb_m: float = Field(default=200.0, gt=0.0)
    sigma_az_deg: float = Field(default=0.5, gt=0.0)
    sigma_el_deg: float = Field(default=0.5, gt=0.0)
    sigma_vb_mps: float = Field(default=5.0, gt=0.0)
    absurd_factor: float = Field(default=10.0, gt=1.0, description="[D] a sigma > factor * default is absurd")


class UTConfig(_Cfg):
    scheme: Literal["symmetric_2n"] = Field(default="symmetric_2n", description="[P] 2n points, no central point")
    weights: Literal["1/2n"] = Field(default="1/2n", description="[P] equal weights")


class TrackerConfig(_Cfg):
    q_accel_var_m2s4: float = Field(default=0.01, ge=0.0, description="[D/S] CV acceleration variance q, m^2/s^4")
    init_L: int = Field(default=2, ge=2, le=20, description="[P/D] 2/L initiation window, scans")  # noqa: N815 (digest name)
    ring_vmin_mps: float = Field(default=30.0, ge=0.0, description="[D] ring gate V_min, m/s")
    ring_vmax_mps: float = Field(default=400.0, gt=0.0, description="[D] ring gate V_max, m/s")
    ring_gate_prob: float = Field(default=0.99, gt=0.0, lt=1.0, description="[D] P_g, chi2 with 3 dof")
    confirm_M: int = Field(default=0, ge=0, description="[P/D] M of M/N; 0 = confirmed on creation")  # noqa: N815 (digest name)
    confirm_N: int = Field(default=0, ge=0, description="[D] N of M/N (window after the 2nd initiating plot)")  # noqa: N815 (digest name)
    drop_K: int = Field(default=3, ge=1, description="[D] drop after K consecutive misses")  # noqa: N815 (digest name)
    assoc_gate_prob: float = Field(default=0.99, gt=0.0, lt=1.0, description="[D] P_G, chi2 with 4 dof")
    association: Literal["nn", "gnn"] = Field(default="gnn", description="[D] fine association")
    gnn_cost_logdet: bool = Field(default=False, description="[D] add ln det S to the GNN cost d^2")
    init_cov: Literal["full", "paper_diagonal"] = Field(default="full", description="[D] P_b(2) form (§2.4)")
    measurement_model: Literal["converted_position", "bistatic_ukf4"] = Field(
        default="converted_position", description="[P] converted plots; bistatic_ukf4 = [D] optional extension"
    )
    scheme: Literal["proposed", "bkf_ukf", "ukf_only", "bkf_only"] = Field(
        default="proposed",
        description="[P] proposed; bkf_ukf = BKF during confirmation then UKF; ukf_only = Cartesian two-plot "
        "init; bkf_only = linear bistatic KF throughout (comparison variants, §2.5)",
    )
    bkf_q_r_m2s4: float = Field(default=10.0, ge=0.0, description="[S] BKF r_b acceleration variance, m^2/s^4")
    bkf_q_ang_rad2s4: float = Field(default=1e-6, ge=0.0, description="[S] BKF angle acceleration var, rad^2/s^4")
    transform: Literal["unscented", "linearized"] = Field(
        default="unscented", description="[E] UT (paper) or first-order Jacobian propagation (test C5)"
    )
    ut: UTConfig = Field(default_factory=UTConfig)

    @model_validator(mode="after")
    def _check(self) -> TrackerConfig:
        if self.ring_vmin_mps >= self.ring_vmax_mps:
            raise ValueError("ring_vmin_mps must be < ring_vmax_mps")
        if self.confirm_M > 0 and self.confirm_N < self.confirm_M:
            raise ValueError("confirm_N must be >= confirm_M when confirm_M > 0")
        return self

    @property
    def gamma4(self) -> float:
        """Association gate chi2_4(P_G) (13.28 for 0.99)."""
        return float(chi2.ppf(self.assoc_gate_prob, 4))

    @property
    def gamma3(self) -> float:
        """Ring-gate ellipse chi2_3(P_g) (11.34 for 0.99)."""
        return float(chi2.ppf(self.ring_gate_prob, 3))


class LimitsConfig(_Cfg):
    rb_max_m: float = Field(default=200_000.0, gt=0.0, description="[D] reject r_b above, m")
    vb_max_abs_mps: float = Field(default=900.0, gt=0.0, description="[D] reject |v_b| above, m/s")
    el_min_deg: float = Field(default=-5.0, ge=-90.0, le=90.0, description="[D] reject elevation below, deg")
    el_max_deg: float = Field(default=89.0, ge=-90.0, le=90.0, description="[D] reject elevation above, deg")
    rb_min_convertible_m: float = Field(default=600.0, ge=0.0, description="[D] no conversion/update below, m")
    near_baseline_sigmas: float = Field(default=3.0, ge=0.0, description="[D] clamp r_b >= -k sigma to 0")
    max_plots_per_scan: int = Field(default=500, ge=1, description="[D] above: clutter burst")
    burst_history_scans: int = Field(default=5, ge=1, description="[D] median window for burst detection")
    burst_factor: float = Field(default=10.0, gt=1.0, description="[E] burst if count > factor * median")
    burst_min_plots: int = Field(default=50, ge=1, description="[E] ... and count >= this")
    max_tentative_tracks: int = Field(default=2000, ge=1, description="[D]")
    max_confirmed_tracks: int = Field(default=500, ge=1, description="[D]")
    reorder_window_scans: int = Field(default=1, ge=0, description="[D] buffered out-of-order scans")
    max_gap_scans: int = Field(default=10, ge=0, description="[D] a larger scan_id gap resets all tracks")

    @model_validator(mode="after")
    def _check(self) -> LimitsConfig:
        if self.el_min_deg >= self.el_max_deg:
            raise ValueError("el_min_deg must be < el_max_deg")
        return self


class PclTrackerConfig(_Cfg):
    """Everything one tracker instance needs (digest §5.1)."""

    geometry: GeometryConfig = Field(default_factory=GeometryConfig)
    measurement_defaults: MeasurementDefaults = Field(default_factory=MeasurementDefaults)
    tracker: TrackerConfig = Field(default_factory=TrackerConfig)
    limits: LimitsConfig = Field(default_factory=LimitsConfig)

    def with_tracker(self, **changes: object) -> PclTrackerConfig:
        """A copy with some tracker fields changed (validated)."""
        tracker = TrackerConfig.model_validate({**self.tracker.model_dump(), **changes})
        return self.model_copy(update={"tracker": tracker})

    def with_limits(self, **changes: object) -> PclTrackerConfig:
        limits = LimitsConfig.model_validate({**self.limits.model_dump(), **changes})
        return self.model_copy(update={"limits": limits})

    def default_sigmas(self) -> tuple[float, float, float, float]:
        """Default sigmas (r_b m, alpha rad, eps rad, v_b m/s)."""
        d = self.measurement_defaults
        return (d.sigma_rb_m, math.radians(d.sigma_az_deg), math.radians(d.sigma_el_deg), d.sigma_vb_mps)
