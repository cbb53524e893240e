"""Aircraft attitude from radar plots (digest 004): the estimator's output, one message per accepted plot.

Frame E of a radar site is flat and radar-centred: x north, y up, z east (``header.frame_id`` names it).
Angles are degrees; a null angle is undefined (see ``flags``). Sigmas are linearised one-sigma values (deg);
while ``LINEARISATION_INVALID`` is flagged they are capped and must not be trusted.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, model_validator

from .base import Covariance, Message, StrictModel
from .estimate import GaussianEstimate, Layout, block_field, check_blocks

AttitudeStatus = Literal["INIT", "CONVERGING", "VALID", "COASTING", "RESET"]

AttitudeFlag = Literal[
    "HEADING_UNDEFINED",
    "PITCH_UNDEFINED",
    "ROLL_UNDEFINED",
    "LINEARISATION_INVALID",
    "GAP_RESET",
    "SCANS_MISSED",
    "NIS_RESET",
    "COVARIANCE_RESET",
    "TRACK_ID_REUSED",
    "OUT_OF_ORDER_DROPPED",
    "DUPLICATE_DROPPED",
    "GATE_REJECTED",
    "INIT_WAITING_SPREAD",
    "EXTRAPOLATED",
    "SMOOTHED",
]

_Deg360 = Field(default=None, ge=0.0, le=360.0)
_Deg180 = Field(default=None, ge=-180.0, le=180.0)
_Deg90 = Field(default=None, ge=-90.0, le=90.0)
_SigmaDeg = Field(default=None, ge=0.0, description="linearised one-sigma, deg")


class RawAttitudeAngles(StrictModel):
    """Angles from the raw (single-look) baseline of §2.6: sliding 3-point FSF, no Kalman filter. Degrees."""

    psi_deg: float | None = _Deg360
    theta_deg: float | None = _Deg90
    gamma_deg: float | None = _Deg180
    psi_los_deg: float | None = _Deg180
    theta_los_deg: float | None = _Deg90
    gamma_los_deg: float | None = Field(default=None, ge=-180.0, le=180.0, description="in gamma_los_form")
    gamma_los_euler_deg: float | None = _Deg180
    aspect_az_deg: float | None = _Deg180
    aspect_el_deg: float | None = _Deg90
    aspect_total_deg: float | None = Field(default=None, ge=0.0, le=180.0)


#: the published 9-state of eq. (3) in the site's frame E (x north, y up, z east)
CA_STATE = Layout(
    ("x", "vx", "ax", "y", "vy", "ay", "z", "vz", "az"),
    ("m", "m/s", "m/s^2", "m", "m/s", "m/s^2", "m", "m/s", "m/s^2"),
)


class AttitudeEstimate(Message):
    """Heading, pitch and roll of one radar target in the earth frame E and the line-of-sight frame (§5.3)."""

    schema_version: ClassVar[int] = 2

    site_id: str = Field(min_length=1, max_length=64)
    target_id: str = Field(min_length=1, max_length=64)
    status: AttitudeStatus
    n_updates: int = Field(ge=0, description="plots in the estimate (buffered plots while INIT)")
    los_x: Literal["radar_to_target", "target_to_radar"] = Field(description="x axis of the LOS frame")
    gamma_los_form: Literal["paper", "euler"] = Field(description="roll definition used in gamma_los_deg")

    # earth frame E: eq. (4) (flight-path heading and pitch, coordinated-flight roll)
    psi_deg: float | None = Field(default=None, ge=0.0, le=360.0, description="heading, clockwise from north")
    theta_deg: float | None = Field(default=None, ge=-90.0, le=90.0, description="pitch, nose up positive")
    gamma_deg: float | None = Field(default=None, ge=-180.0, le=180.0, description="roll, right wing down positive")
    sigma_psi_deg: float | None = _SigmaDeg
    sigma_theta_deg: float | None = _SigmaDeg
    sigma_gamma_deg: float | None = _SigmaDeg

    # LOS frame: eq. (5)
    psi_los_deg: float | None = _Deg180
    theta_los_deg: float | None = _Deg90
    gamma_los_deg: float | None = Field(default=None, ge=-180.0, le=180.0, description="in gamma_los_form")
    gamma_los_euler_deg: float | None = Field(default=None, ge=-180.0, le=180.0, description="Euler roll vs LOS")
    sigma_psi_los_deg: float | None = _SigmaDeg
    sigma_theta_los_deg: float | None = _SigmaDeg
    sigma_gamma_los_deg: float | None = _SigmaDeg
    sigma_gamma_los_euler_deg: float | None = _SigmaDeg
    angle_cov_los_deg2: Covariance | None = Field(
        default=None, description="3x3 covariance of (psi_los, theta_los, gamma_los), deg^2"
    )

    # aspect of the radar in body axes
    aspect_az_deg: float | None = Field(default=None, ge=-180.0, le=180.0, description="0 nose-on, + starboard")
    aspect_el_deg: float | None = Field(default=None, ge=-90.0, le=90.0, description="+ above the body x-z plane")
    aspect_total_deg: float | None = Field(default=None, ge=0.0, le=180.0, description="0 head-on, 180 tail-on")
    sigma_aspect_az_deg: float | None = _SigmaDeg
    sigma_aspect_el_deg: float | None = _SigmaDeg
    sigma_aspect_total_deg: float | None = _SigmaDeg

    # LOS geometry of the filtered position
    range_m: float | None = Field(default=None, ge=0.0, description="slant range, m")
    az_deg: float | None = Field(default=None, ge=0.0, le=360.0, description="azimuth, clockwise from north")
    el_deg: float | None = Field(default=None, ge=-90.0, le=90.0, description="elevation")

    # filtered Cartesian state in E
    estimate: GaussianEstimate | None = block_field(CA_STATE, "the filtered state in the site's frame", optional=True)
    speed_mps: float | None = Field(default=None, ge=0.0)
    turn_rate_dps: float | None = Field(default=None, description="d(psi)/dt, deg/s, + clockwise")
    load_factor: float | None = Field(default=None, description="normal load factor n, dimensionless")
    nis: float | None = Field(default=None, ge=0.0, description="normalised innovation squared of this plot")
    model_probabilities: list[float] | None = Field(
        default=None,
        max_length=8,
        description="IMM model probabilities mu_j, in the order of the estimator's imm_models (null: single model)",
    )

    flags: list[AttitudeFlag] = Field(default_factory=list, max_length=16)
    raw: RawAttitudeAngles | None = Field(default=None, description="raw-baseline angles (§2.6), diagnostic")

    @model_validator(mode="after")
    def _shapes(self) -> AttitudeEstimate:
        check_blocks(self)
        if self.angle_cov_los_deg2 is not None and len(self.angle_cov_los_deg2) != 3:
            raise ValueError("angle_cov_los_deg2 must be 3x3")
        return self
