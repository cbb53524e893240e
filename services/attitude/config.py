"""Parameters of the attitude estimator (digest 004, §5.2) with the digest's defaults and units.

Tags in the descriptions follow the digest: [PAPER] stated in the paper, [RECON] rebuilt from the OCR,
[CHOICE] a default fixed by the digest because the paper is silent, [EXT] a service extension of the digest.
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, SerializerFunctionWrapHandler, model_serializer, model_validator

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


Preset = Literal["manoeuvre", "paper"]
_UNSET = object()


class MotionModel(BaseModel):
    """One motion model of the interacting-multiple-model (IMM) bank, over the 9-state of eq. (3) (plus the turn
    rate omega in a bank with a ``ct`` model, imm.py).

    * ``ca``: the paper's constant-acceleration model driven by random jerk (eq. 3, M = S^T D S) of standard
      deviation ``sigma_jerk_mps3`` (m/s^3) on the horizontal axes (x north, z east) and
      ``vertical_jerk_factor * sigma_jerk_mps3`` on the vertical one (y up; 1: the paper's isotropic jerk);
    * ``singer``: the acceleration is mean-reverting (first-order Markov, correlation time ``tau_s``) with
      stationary standard deviation ``sigma_accel_mps2``: non-manoeuvring flight, whose acceleration wanders
      about zero (turbulence, pilot corrections) instead of drifting like the CA model's random walk;
    * ``ct``: the nearly coordinated turn (models.ct_predict): a turn-rate state omega, a random walk of
      ``sigma_turn_rate_dps`` (deg/s over 1 s), and a horizontal acceleration omega x V_h plus a Singer deviation
      (``sigma_accel_mps2``, ``tau_s``; the vertical axis a Singer model of the same); ``ct_prediction`` chooses
      the Gauss-Hermite quadrature over omega (default) or the EKF.

    ``sojourn_s``: mean time (s) the aircraft stays in this mode; the Markov switching probability over a step
    dt is 1 - exp(-dt / sojourn_s), shared equally among the other models (or among those named in
    ``exits_to``: a turn ends in straight flight or a new onset, not in another model).

    ``exit_heading_change_deg`` (ct only; None: off): the turn ends after a mean heading change of this many
    degrees instead of a mean time: the exit rate is |omega^| / dpsi per second (omega^ the model's turn-rate
    estimate), at least 1 / ``sojourn_s`` (which is then the longest mean sojourn, that of a turn at omega^ = 0).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(min_length=1, max_length=32, description="label in outputs and docs")
    kind: Literal["ca", "singer", "ct"] = Field(
        description="ca: random jerk (eq. 3); singer: mean-reverting acceleration; ct: nearly coordinated turn"
    )
    sigma_jerk_mps3: float | None = Field(default=None, ge=0.0, le=100.0, description="ca: jerk std, m/s^3")
    vertical_jerk_factor: float = Field(
        default=1.0,
        ge=0.0,
        le=10.0,
        description="ca: the vertical axis's (y, up) jerk std is this times sigma_jerk_mps3 (1: isotropic jerk)",
    )
    sigma_accel_mps2: float | None = Field(
        default=None,
        gt=0.0,
        le=100.0,
        description="singer: accel std; ct: std of the deviation from a coordinated turn",
    )
    tau_s: float | None = Field(default=None, gt=0.0, le=1e5, description="singer, ct: correlation time, s")
    sigma_turn_rate_dps: float | None = Field(
        default=None, ge=0.0, le=100.0, description="ct: random-walk std of the turn rate over 1 s, deg/s"
    )
    ct_prediction: Literal["quadrature", "ekf"] = Field(
        default="quadrature",
        description="ct: prediction by Gauss-Hermite quadrature over the turn rate (exact given omega) or by the "
        "EKF's linearisation in omega",
    )
    sojourn_s: float = Field(gt=0.0, le=1e7, description="mean time in this mode, s")
    exit_heading_change_deg: float | None = Field(
        default=None,
        gt=0.0,
        le=3600.0,
        description="ct: mean heading change of a turn, deg: exit rate max(|omega^| / this, 1 / sojourn_s) per "
        "second, omega^ the model's turn-rate estimate; None: the exit rate 1 / sojourn_s",
    )
    exits_to: tuple[str, ...] | None = Field(
        default=None,
        max_length=8,
        description="names of the models this mode switches to (its switching probability shared equally among "
        "them); None: all the others",
    )

    @model_validator(mode="after")
    def _parameters(self) -> MotionModel:
        if self.kind == "ca" and (self.sigma_jerk_mps3 is None or self.sigma_accel_mps2 is not None):
            raise ValueError("a ca model takes sigma_jerk_mps3 (and no sigma_accel_mps2)")
        if self.kind in ("singer", "ct") and (
            self.sigma_accel_mps2 is None or self.tau_s is None or self.sigma_jerk_mps3 is not None
        ):
            raise ValueError(f"a {self.kind} model takes sigma_accel_mps2 and tau_s (and no sigma_jerk_mps3)")
        if self.kind != "ca" and self.vertical_jerk_factor != 1.0:
            raise ValueError("vertical_jerk_factor is the ca model's (and only its)")
        if self.kind != "ct" and self.exit_heading_change_deg is not None:
            raise ValueError("exit_heading_change_deg is the ct model's (and only its)")
        if (self.kind == "ct") != (self.sigma_turn_rate_dps is not None):
            raise ValueError("sigma_turn_rate_dps is the ct model's (and only its) turn-rate noise")
        return self

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """The dump leaves out ``vertical_jerk_factor`` at its default 1 and ``exit_heading_change_deg`` when
        None, so configurations echoed in outputs (``fixstream mc``'s JSON) stay as they were before the fields
        existed; they read back as the defaults."""
        out: dict[str, Any] = handler(self)
        if self.vertical_jerk_factor == 1.0:
            out.pop("vertical_jerk_factor", None)
        if self.exit_heading_change_deg is None:
            out.pop("exit_heading_change_deg", None)
        return out

    @property
    def q_omega(self) -> float:
        """ct: spectral density of the turn rate's random walk, rad^2/s^3."""
        s = math.radians(self.sigma_turn_rate_dps or 0.0)
        return s * s


#: the default preset's first model bank (issue 15, before the coordinated-turn model): straight flight with
#: wandering acceleration, a manoeuvre model (turns, pull-ups) and a manoeuvre-onset model (roll-in, roll-out,
#: load-factor steps); kept for comparison (bench_attitude_manoeuvre's ``manoeuvre_ca``)
CA_MODELS: tuple[MotionModel, ...] = (
    MotionModel(name="straight", kind="singer", sigma_accel_mps2=0.2, tau_s=20.0, sojourn_s=300.0),
    MotionModel(name="manoeuvre", kind="ca", sigma_jerk_mps3=0.3, sojourn_s=60.0),
    MotionModel(name="onset", kind="ca", sigma_jerk_mps3=1.0, sojourn_s=20.0),
)

#: the manoeuvre-robust model bank of the default preset (docs/attitude.md, "Manoeuvres"):
#:
#: * ``straight``: nearly constant velocity (a Singer acceleration of 0.2 m/s^2 that decorrelates in 1 s): the
#:   most accurate model of level flight at these radar errors, and the one that forgets a turn's acceleration
#:   within a scan when the turn ends;
#: * ``turn``: the nearly coordinated turn (CT) with a turn-rate state (models.ct_predict): a steady turn
#:   predicted as a turn, its acceleration turning with the velocity; it ends in straight flight (or a new onset);
#: * ``onset``: the paper's CA model at sigma_j = 1 m/s^3: roll-in, roll-out, pull-ups, load-factor steps.
MANOEUVRE_MODELS: tuple[MotionModel, ...] = (
    MotionModel(name="straight", kind="singer", sigma_accel_mps2=0.2, tau_s=1.0, sojourn_s=200.0),
    MotionModel(
        name="turn",
        kind="ct",
        sigma_accel_mps2=0.3,
        tau_s=5.0,
        sigma_turn_rate_dps=0.1,
        sojourn_s=20.0,
        exits_to=("straight", "onset"),
    ),
    MotionModel(name="onset", kind="ca", sigma_jerk_mps3=1.0, sojourn_s=20.0),
)

#: the parameters a preset sets (any of them given explicitly overrides the preset)
PRESETS: dict[str, dict[str, Any]] = {
    "paper": {
        "motion": "single",
        "nis_gate": 21.1,
        "gate_accel_mps2": None,
        "nis_reset_count": 3,
        "valid_nis_window": None,
        "heading_sigma_factor": 3.0,
    },
    "manoeuvre": {
        "motion": "imm",
        "nis_gate": 21.1,
        "gate_accel_mps2": 30.0,
        "nis_reset_count": 3,
        "valid_nis_window": 5,
        "heading_sigma_factor": 2.0,
    },
}


class AttitudeConfig(BaseModel):
    """Configuration of one :class:`~services.attitude.core.AttitudeCore` (one radar site, many targets)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    preset: Preset = Field(
        default="manoeuvre",
        description="manoeuvre: the IMM filter, manoeuvre gate and consistency-checked VALID (the default); paper: "
        "the digest's single constant-acceleration filter (its acceptance tests use it). Sets the parameters "
        "listed in PRESETS; any of them given explicitly wins",
    )

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
    motion: Literal["single", "imm"] = Field(
        default="imm",
        description="single: the paper's filter with sigma_jerk_mps3; imm: interacting multiple models (imm_models)",
    )
    imm_models: tuple[MotionModel, ...] = Field(
        default=MANOEUVRE_MODELS, min_length=1, max_length=8, description="the IMM's motion models [EXT]"
    )
    imm_initial_probabilities: tuple[float, ...] | None = Field(
        default=None, description="model probabilities at the FSF start (None: 0.9 on the first, the rest shared)"
    )
    gate_accel_mps2: float | None = Field(
        default=30.0,
        gt=0.0,
        description="manoeuvre gate [EXT]: a plot is gated only if it is outside nis_gate even for an unmodelled "
        "acceleration change of this size over the step (S + (a dt^2 / 2)^2 I, the widest model); None: the plain "
        "NIS gate of the paper preset",
    )
    valid_nis_window: int | None = Field(
        default=5,
        ge=1,
        le=100,
        description="VALID also needs the mean NIS of the last this-many plots inside the chi2(3 W) 99 % bound "
        "(the estimate's covariance explains its innovations) [EXT]; None: sigmas only (paper preset)",
    )
    smoother_lag_scans: int = Field(
        default=0,
        ge=0,
        le=10,
        description="IMM only: besides each real-time estimate, emit the fixed-lag smoothed estimate of the plot this "
        "many plots back (flag SMOOTHED, smoother.py) [EXT]; 0: off",
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
        default=2.0, ge=0.0, description="heading undefined while V_h < factor x sigma(V_h); 0 disables the rule"
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

    @model_validator(mode="before")
    @classmethod
    def _apply_preset(cls, data: Any) -> Any:
        """Fill every preset parameter not given explicitly from the preset (default ``manoeuvre``)."""
        if not isinstance(data, dict):
            return data
        preset = data.get("preset", "manoeuvre")
        if preset not in PRESETS:
            return data  # the field's own validation reports it
        out = dict(data)
        for name, value in PRESETS[preset].items():
            if out.get(name, _UNSET) is _UNSET:
                out[name] = value
        return out

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
        names = [m.name for m in self.imm_models]
        for m in self.imm_models:
            if m.exits_to is not None and (not m.exits_to or not set(m.exits_to) <= set(names) - {m.name}):
                raise ValueError(f"imm_models: {m.name}.exits_to must name other models of the bank")
        if self.smoother_lag_scans and self.motion != "imm":
            raise ValueError("smoother_lag_scans needs motion 'imm' (the smoother augments the IMM's models)")
        mu0 = self.imm_initial_probabilities
        if mu0 is not None and (
            len(mu0) != len(self.imm_models) or any(not 0.0 < m <= 1.0 for m in mu0) or abs(sum(mu0) - 1.0) > 1e-9
        ):
            raise ValueError("imm_initial_probabilities: one positive probability per model, summing to 1")
        return self

    def initial_probabilities(self) -> tuple[float, ...]:
        """mu_0 of the IMM at the FSF start: the configured values, or 0.9 on the first model and the rest shared."""
        if self.imm_initial_probabilities is not None:
            return self.imm_initial_probabilities
        m = len(self.imm_models)
        return (1.0,) if m == 1 else (0.9, *([0.1 / (m - 1)] * (m - 1)))

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
