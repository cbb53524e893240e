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
from .imm import ImmModels

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


Preset = Literal["robust", "paper"]

#: what ``preset: paper`` changes from the defaults (= ``preset: robust``), unless the field is given explicitly:
#: the digest's configuration (§5.1): one CV model with q = 0.01, M = 0, initiation suppressed in clutter bursts
PAPER_PRESET: dict[str, object] = {
    "motion_model": "cv",
    "confirm_M": 0,
    "confirm_N": 0,
    "burst_initiation": "suppress",
}


class TrackerConfig(_Cfg):
    """Tracker parameters. ``preset`` picks the defaults of the fields it controls (:data:`PAPER_PRESET`):

    * ``robust`` (the default) [E]: an IMM over CV models of low and high process noise (manoeuvres up to
      about 2 g), M/N = 3/4 confirmation (false-track control, digest §4.4 E5), and initiation from the
      strongest plots by SNR during a clutter burst (digest §5.6's alternative);
    * ``paper``: the digest's configuration (§5.1): one CV model with q = 0.01, M = 0 (confirmed on
      creation), no initiation in a clutter burst.

    A field given explicitly always wins over the preset.
    """

    preset: Preset = Field(default="robust", description="[E] robust (default) or paper: see PAPER_PRESET")
    motion_model: Literal["cv", "imm"] = Field(
        default="imm", description="[E] cv: one CV model with q (paper); imm: IMM over CV models imm_q_m2s4"
    )
    q_accel_var_m2s4: float = Field(default=0.01, ge=0.0, description="[D/S] CV acceleration variance q, m^2/s^4")
    imm_q_m2s4: tuple[float, ...] = Field(
        default=(0.001, 1.0, 25.0, 400.0),
        min_length=1,
        max_length=8,
        description="[E] IMM: q of each CV model, m^2/s^4 (straight flight, gentle, ~0.5 g and ~2 g manoeuvres)",
    )
    imm_sojourn_s: tuple[float, ...] = Field(
        default=(1200.0, 120.0, 60.0, 15.0),
        min_length=1,
        max_length=8,
        description="[E] IMM: mean time in each model, s (p_jj = exp(-tau/s_j))",
    )
    imm_mu0: tuple[float, ...] = Field(
        default=(0.7, 0.1, 0.1, 0.1),
        min_length=1,
        max_length=8,
        description="[E] IMM: model probabilities of a new track",
    )
    imm_likelihood: Literal["bistatic", "position"] = Field(
        default="bistatic",
        description="[E] IMM model likelihoods from the 4-D bistatic plot (uses v_b; the gating prediction is the "
        "mixture of the models' images) or from the converted position",
    )
    burst_initiation: Literal["suppress", "strongest_snr"] = Field(
        default="strongest_snr",
        description="[D] in a clutter burst: no initiation (suppress), or initiate from the max_plots_per_scan "
        "strongest plots by SNR",
    )
    init_L: int = Field(default=2, ge=2, le=20, description="[P/D] 2/L initiation window, scans")  # noqa: N815 (digest name)
    ring_vmin_mps: float = Field(default=30.0, ge=0.0, description="[D] ring gate V_min, m/s")
    ring_vmax_mps: float = Field(default=400.0, gt=0.0, description="[D] ring gate V_max, m/s")
    ring_gate_prob: float = Field(default=0.99, gt=0.0, lt=1.0, description="[D] P_g, chi2 with 3 dof")
    confirm_M: int = Field(default=3, ge=0, description="[P/D] M of M/N; 0 = confirmed on creation")  # noqa: N815 (digest name)
    confirm_N: int = Field(default=4, ge=0, description="[D] N of M/N (window after the 2nd initiating plot)")  # noqa: N815 (digest name)
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
        if self.preset == "paper":
            for name, value in PAPER_PRESET.items():
                if name not in self.model_fields_set:
                    object.__setattr__(self, name, value)  # frozen model: set once, while validating
        if self.motion_model == "imm":
            r = len(self.imm_q_m2s4)
            if len(self.imm_sojourn_s) != r or len(self.imm_mu0) != r:
                raise ValueError("imm_q_m2s4, imm_sojourn_s and imm_mu0 need one value per model")
            if min(self.imm_q_m2s4) < 0.0 or min(self.imm_sojourn_s) <= 0.0 or min(self.imm_mu0) < 0.0:
                raise ValueError("imm_q_m2s4 >= 0, imm_sojourn_s > 0 and imm_mu0 >= 0 are required")
            if abs(sum(self.imm_mu0) - 1.0) > 1e-6:
                raise ValueError("imm_mu0 must sum to 1")
            if self.scheme not in ("proposed", "ukf_only") or self.measurement_model != "converted_position":
                raise ValueError(
                    "motion_model imm runs with scheme proposed or ukf_only and measurement_model converted_position"
                )
        if self.ring_vmin_mps >= self.ring_vmax_mps:
            raise ValueError("ring_vmin_mps must be < ring_vmax_mps")
        if self.confirm_M > 0 and self.confirm_N < self.confirm_M:
            raise ValueError("confirm_N must be >= confirm_M when confirm_M > 0")
        return self

    @property
    def imm_models(self) -> ImmModels:
        """The IMM model set (q_j, sojourn times, initial probabilities)."""
        return ImmModels(self.imm_q_m2s4, self.imm_sojourn_s, self.imm_mu0)

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
    min_init_interval_s: float = Field(
        default=0.5, ge=0.0, description="[E] two plots closer in time never start a track (rates undefined), s"
    )
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

    @classmethod
    def paper(cls, **sections: object) -> PclTrackerConfig:
        """The digest's configuration (``preset: paper``), other sections as given (e.g. ``geometry=...``)."""
        return cls.model_validate({**sections, "tracker": TrackerConfig(preset="paper")})

    def with_tracker(self, **changes: object) -> PclTrackerConfig:
        """A copy with some tracker fields changed (validated)."""
        # only the explicitly set fields are carried over, so a changed preset applies to the others
        kept = self.tracker.model_dump(include=self.tracker.model_fields_set)
        tracker = TrackerConfig.model_validate({**kept, **changes})
        return self.model_copy(update={"tracker": tracker})

    def with_limits(self, **changes: object) -> PclTrackerConfig:
        limits = LimitsConfig.model_validate({**self.limits.model_dump(), **changes})
        return self.model_copy(update={"limits": limits})

    def default_sigmas(self) -> tuple[float, float, float, float]:
        """Default sigmas (r_b m, alpha rad, eps rad, v_b m/s)."""
        d = self.measurement_defaults
        return (d.sigma_rb_m, math.radians(d.sigma_az_deg), math.radians(d.sigma_el_deg), d.sigma_vb_mps)
