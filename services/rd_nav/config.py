"""Parameters of the RD-LBL navigation core (digest 002), with the digest's defaults and units.

Tags in the descriptions follow the digest: [P] paper, [R] reconstruction, [E] engineering addition,
[D] derived/reference simulation. Every [E]/[R]/[D] value is a parameter here so it can be changed.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator


class RdNavConfig(BaseModel):
    """Configuration of :class:`services.rd_nav.core.RdNavCore` (one instance per moving AUV)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    auv_id: str = Field(default="auv", min_length=1, description="the moving AUV this instance navigates")
    frame_id: str = Field(default="base_ned", description="frame of the output positions (base-station NED)")
    seed: int = Field(default=0, description="seed of the particle filter's random generator")

    # ---- particle filter (§4.4) ----
    n_particles: int = Field(default=1000, ge=10, description="N [E] (§4.4 step 1; 300..2000 equivalent)")
    r0_m: float = Field(default=10.0, gt=0.0, description="initial disc radius R0, m [E]")
    process_model: Literal["dr_errors", "paper"] = Field(
        default="dr_errors",
        description="dr_errors: particles (and the EKF) carry the DR error states of services/rd_nav/drift.py "
        "(speed bias, time-driven; heading and scale errors, distance-driven) [E]; paper: the digest's white "
        "q = q_rel*path + q_abs per q_step_s (+ q_drift_mps) [E, §4.4]",
    )
    # ---- DR error model (process_model dr_errors; the digest's §5.4 sensor errors by default) ----
    dr_speed_bias_mps: float = Field(
        default=0.05, ge=0.0, description="speed bias (additive speed error), Gauss-Markov sigma, m/s [D §5.4]"
    )
    dr_speed_bias_tau_s: float = Field(default=300.0, gt=0.0, description="its correlation time, s [D §5.4]")
    dr_heading_sigma_deg: float = Field(default=2.0, ge=0.0, description="heading error Gauss-Markov sigma, deg [D]")
    dr_heading_tau_s: float = Field(default=300.0, gt=0.0, description="its correlation time, s [D §5.4]")
    dr_speed_scale: float = Field(
        default=0.0, ge=0.0, description="speed scale-factor error Gauss-Markov sigma (fraction of the speed) [E]"
    )
    dr_speed_scale_tau_s: float = Field(default=300.0, gt=0.0, description="its correlation time, s [E]")
    dr_speed_white_mps: float = Field(default=0.02, ge=0.0, description="white speed noise per sample, m/s [D]")
    dr_heading_white_deg: float = Field(default=0.5, ge=0.0, description="white heading noise per sample, deg [D]")
    dr_sample_period_s: float = Field(default=1.0, gt=0.0, description="DVL/heading sample period, s [D]")
    dr_floor_m: float = Field(
        default=0.1, ge=0.0, description="isotropic model floor per dr_floor_path_m of path (turns, speed steps), m [E]"
    )
    dr_floor_path_m: float = Field(default=15.0, gt=0.0, description="path the floor refers to (one REF cycle), m [E]")
    predict_lag_s: float = Field(
        default=40.0,
        gt=0.0,
        description="dr_errors: without cycles, the filter is predicted up to this long before the latest sensor "
        "time (long gaps stay within the DR buffer) [E]",
    )
    q_rel: float = Field(default=0.07, ge=0.0, description="process noise per step, fraction of DR path [E]")
    q_abs_m: float = Field(default=0.3, ge=0.0, description="process noise per step, absolute, m [E]")
    q_step_s: float = Field(default=10.0, gt=0.0, description="time step the q figures refer to (one REF cycle), s [E]")
    max_predict_steps: int = Field(
        default=500,
        ge=1,
        le=1_000_000,
        description="dr_errors: a prediction takes at most this many steps; a longer gap (beyond max_predict_steps x "
        "q_step_s, 5,000 s at the defaults) is predicted in longer steps, so that one input stamped far ahead (a time "
        "jump) costs milliseconds, not hours [E]",
    )
    q_drift_mps: float = Field(
        default=0.05,
        ge=0.0,
        description="per-axis Gauss-Markov DR velocity error (correlation time q_drift_tau_s) whose path integral "
        "widens the cloud from the last complete, well-conditioned update on (lost or rejected cycles and weak "
        "geometry do not observe it); nothing while every cycle updates the filter; 0: the digest's q only, m/s [E]",
    )
    q_drift_tau_s: float = Field(default=300.0, gt=0.0, description="correlation time of that DR velocity error, s [E]")
    q_drift_weak_geometry: bool = Field(
        default=True,
        description="a complete cycle flagged DEGRADED_GEOMETRY does not end the drift growth (it cannot see the "
        "DR velocity error along its weak direction) [E]",
    )
    q_dr_invalid_mps: float = Field(
        default=1.5, ge=0.0, description="extra diffusion per second while DR is invalid (frozen), m/s [E]"
    )
    roughening_m: float = Field(default=0.1, ge=0.0, description="roughening jitter after resampling, m [E]")
    degenerate_neff_fraction: float = Field(
        default=0.02,
        ge=0.0,
        lt=1.0,
        description="after an update leaving N_eff below this fraction of N, positions are redrawn from the "
        "Gaussian posterior of the prior cloud's moments and the linearised cycle (0: never) [E]",
    )
    roughening_shrink: bool = Field(
        default=True,
        description="shrink the resampled cloud towards its mean as the jitter spreads it (covariance kept, Liu & "
        "West); false: the digest's plain jitter, which widens the cloud by 0.1 m at every resampling [E]",
    )
    resample_fraction: float = Field(default=0.5, gt=0.0, le=1.0, description="resample when N_eff < f*N [E]")
    epsilon: float = Field(default=0.05, ge=0.0, lt=1.0, description="robust outlier weight eps [E]")
    outlier_m2: float = Field(default=25.0, gt=0.0, description="outlier floor exp(-m2/2) in the mixture [E]")
    estimate: Literal["mean", "map"] = Field(default="mean", description="Eq. (6) weighted mean, or MAP [P]")
    map_weight_threshold: float = Field(default=0.01, gt=0.0, le=1.0, description="MAP needs weight > this [P]")

    # ---- measurement model (§4.2) ----
    sigma_t_s: float = Field(default=0.2e-3, gt=0.0, description="arrival-time noise per arrival, s [E, REF]")
    sigma_f_s: float = Field(default=0.0, ge=0.0, description="follower detection/reply jitter, s [E]")
    sigma_c_floor_mps: float = Field(default=0.05, ge=0.0, description="floor on the reported sigma_c, m/s [E]")
    include_sound_speed_in_r: bool = Field(default=True, description="(sigma_c/c)^2 s s^T term in R [D]")
    sigma_node_m: float = Field(default=0.0, ge=0.0, description="node coordinate 1-sigma per axis, m [E]")
    use_packet_pos_sigma: bool = Field(default=True, description="also use the packets' pos_sigma_m [E]")
    motion_compensation: bool = Field(default=True, description="intra-cycle DR displacement delta_j [E]")
    sigma_dr_velocity_mps: float = Field(
        default=0.05, ge=0.0, description="DR velocity error per axis in R's motion-compensation term, m/s [E]"
    )
    use_reported_reply_delay: bool = Field(default=True, description="tau_j from the follower packet [E]")
    default_tau_s: list[float] = Field(
        default_factory=list, description="tau per reply slot when neither packet nor assignment gives it, s [E]"
    )
    window_tol_m: float = Field(default=20.0, ge=0.0, description="validity window tolerance on s_j, m [D]")
    use_partial_cycles: bool = Field(default=True, description="use M = 1 cycles (flag PARTIAL) [E]")

    # ---- sound speed (§7.4) ----
    default_c_mps: float = Field(default=1500.0, gt=0.0, description="fallback sound speed, m/s [E]")
    c_plausible_mps: tuple[float, float] = Field(default=(1400.0, 1600.0), description="plausible c, m/s [E]")
    sigma_c_fallback_mps: float = Field(default=5.0, gt=0.0, description="sigma_c while on the fallback [E]")

    # ---- gating and re-initialisation (§4.4 step 8) ----
    gating: bool = Field(default=True, description="NIS gate at chi2_{M,gate_probability} [E]")
    gate_probability: float = Field(default=0.999, gt=0.0, lt=1.0)
    gate_after_updates: int = Field(
        default=4,
        ge=0,
        description="no NIS gate (and no late-arrival test) until this many complete cycles have updated the filter "
        "since its start or re-seed: the first updates from the R0 disc leave a handful of particles, whose spread "
        "judges an innovation poorly (the robust likelihood still bounds an outlier's pull) [E]",
    )
    drop_single_outlier: bool = Field(
        default=True, description="use a gated-out cycle without one late follower if the rest passes [E]"
    )
    outlier_only_if_gated: bool = Field(
        default=True,
        description="look for one late arrival only in a cycle the NIS gate rejects; false: also in a cycle inside "
        "the gate whose residual alone fails chi2_1 along one arrival (with M = 2 a position error looks the same: "
        "in fault-free runs a 3-sigma excursion was then taken for a late leader and the lock lost) [E]",
    )
    reinit: bool = Field(default=True, description="snapshot re-initialisation after K rejections [E]")
    reinit_k: int = Field(default=3, ge=1, description="K consecutive gated-out cycles [E]")
    reinit_k_same_outlier: int = Field(
        default=6, ge=1, description="... when one beacon's late arrival explains every one of them [E]"
    )
    reinit_late_arrival_min_m: float = Field(
        default=15.0, ge=0.0, description="... and that late arrival is at least this late (c*delay), m [E]"
    )
    reinit_consistency_m: float = Field(default=5.0, gt=0.0, description="K snapshot fixes agree within, m [E]")
    reinit_drift_sigma: float = Field(
        default=3.0,
        ge=0.0,
        description="the consistency tolerance grows by this many DR velocity sigmas (sqrt(2) sigma_dr_velocity_mps) "
        "times the fixes' time span; 0: the digest's fixed tolerance [E]",
    )
    reinit_strict_chain: bool = Field(
        default=False,
        description="the K fixes must come from K consecutive cycles (a partial cycle breaks the run, and a partial "
        "cycle inside the gate ends it); off: partial cycles count towards K without a fix [E]",
    )
    reinit_max_distance_m: float = Field(default=1000.0, gt=0.0, description="and lie within this of x_hat, m [E]")
    reinit_crlb_scale: float = Field(default=4.0, gt=0.0, description="re-seed cov = scale*P_CRLB + extra [E]")
    reinit_extra_var_m2: float = Field(default=0.25, ge=0.0, description="extra re-seed variance, m^2 [E]")

    # ---- snapshot Gauss-Newton (§4.5) ----
    gn_max_iter: int = Field(default=30, ge=1)
    gn_step_limit_m: float = Field(default=200.0, gt=0.0)
    gn_tol_m: float = Field(default=1e-3, gt=0.0)

    # ---- cycle assembly (§7.3 S3) ----
    cycle_period_s: float = Field(default=10.0, gt=0.0, description="T_c when no assignment says, s [E]")
    max_cycle_span_s: float = Field(
        default=9.0, gt=0.0, description="close a cycle this long after t1 when the set is unknown, s [E]"
    )
    t_pkt_s: float = Field(default=0.4, ge=0.0, description="packet length T_pkt, s [E]")
    close_margin_s: float = Field(default=0.5, ge=0.0, description="margin after the last expected arrival, s [E]")
    pos_check_tol_m: float = Field(default=1.0, gt=0.0, description="broadcast vs node table, m [E]")
    clock_jump_tol_s: float = Field(
        default=0.05, gt=0.0, description="step of (t_rx_local - stamp) that counts as a clock jump, s [E]"
    )
    fleet_ids: list[str] = Field(default_factory=list, description="known senders (empty: any) [E]")
    base_node_id: str = Field(default="base", description="node id of the base station dock(s) [E]")
    node_table_ned_m: dict[str, tuple[float, float, float]] = Field(
        default_factory=dict, description="node_id -> surveyed (north, east, depth), m [P]/[E]"
    )

    # ---- dead reckoning (§4.3, §7.3 S4) ----
    dvl_hold_s: float = Field(default=5.0, ge=0.0, description="hold the last DVL velocity this long, s [E]")
    heading_hold_s: float = Field(default=5.0, ge=0.0, description="hold the last heading this long, s [E]")
    dr_interpolation: Literal["hold", "linear"] = Field(
        default="linear", description="between DVL/attitude samples: zero-order hold or trapezoid [E]"
    )
    dr_buffer_s: float = Field(default=120.0, gt=10.0, description="DR ring-buffer length, s [E]")
    assume_depth_m: float | None = Field(default=None, description="depth if no Depth message has come, m [E]")

    # ---- outputs ----
    ekf_shadow: bool = Field(default=True, description="run the EKF baseline as a cross-check [E]")
    ekf_reseed_on_pf_reinit: bool = Field(default=True, description="re-seed the EKF when the PF does [E]")
    emit_propagated_after_cycle: bool = Field(default=True, description="also emit x_hat carried to now [E]")
    propagated_fix_period_s: float = Field(
        default=1.0, ge=0.0, description="DR-propagated fixes on sensor time, s (0: none) [E]"
    )
    dr_only_after_cycles: int = Field(default=3, ge=1, description="status DR_ONLY after this many cycles [E]")
    degraded_drms_m: float = Field(default=5.0, gt=0.0, description="DEGRADED_GEOMETRY above this CRLB DRMS [E]")
    degraded_cond: float = Field(default=1e6, gt=1.0, description="or above this cond(H) [E]")
    init_from_snapshots: bool = Field(
        default=True, description="without a start position, initialise from K consistent snapshots [E]"
    )

    @model_validator(mode="after")
    def _lag(self) -> RdNavConfig:
        if self.predict_lag_s + self.max_cycle_span_s >= self.dr_buffer_s:
            raise ValueError("predict_lag_s + max_cycle_span_s must be shorter than dr_buffer_s")
        return self
