"""Terrain-aided navigation (digest 001): the per-evaluation verdict and the horizontal/vertical fix.

The estimator is the recurrent-search terrain navigator of ``services/terrain_nav``. Its inputs are the
existing :class:`~schemas.navigation.InsSample`, :class:`~schemas.navigation.RadioAltimeter`,
:class:`~schemas.navigation.BaroAltitude` and :class:`~schemas.navigation.NavReset` streams.

Horizontal quantities are in the map frame of the reference DEM (``header.frame_id``, default ``map``):
``x`` longitudinal (map axis 0), ``z`` transverse (map axis 1), metres. Corrections follow the digest's
sign convention ``true = indicated + correction``. Hypothesis offsets are in map cells.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, model_validator

from .base import Message
from .estimate import GaussianEstimate, Layout, block_field, check_blocks

#: the verdict's state word (digest §5.3): why a fix was or was not issued, or a stream status
VerdictState = Literal[
    "ACQUIRING",  # C1 false: not enough valid cell measurements in the window yet
    "NO_FIX_FIT",  # C1 held, C2 (goodness of fit) failed first
    "NO_FIX_AMBIGUOUS",  # C1, C2 held, C3 (unique and sharp extremum) failed first
    "NO_FIX_UNSTABLE",  # C1-C3 held, C4 (argmin stable over the last N_R measurements) failed
    "FIX",  # C1-C4 held: a TerrainFix accompanies this verdict
    "OUT_OF_ZONE",  # the INS position is outside the correction zone (no measurement formed)
    "GAP",  # an INS gap over the synchronisation limit: radio-altimeter samples were dropped
    "RESET",  # the estimator state was cleared (NavReset)
]


class TerrainVerdict(Message):
    """Outcome of one evaluation of the reliability conditions C1-C4 (one per group of N_p cell crossings).

    Status verdicts (``OUT_OF_ZONE``, ``GAP``, ``RESET``) carry no evaluation: their optional fields are
    ``None`` and the condition flags are ``False``.
    """

    state: VerdictState
    valid: bool = Field(description="C1 and C2 and C3 and C4: a fix is issued with this verdict")
    c1_enough_data: bool = Field(description="C1: N_valid > N_min")
    c2_fit: bool = Field(description="C2: F_min/N_valid < mu_F * L_zk")
    c3_unique: bool = Field(description="C3: D_max < mu1 + mu2 * phi(N_valid)")
    c4_stable: bool = Field(description="C4: argmin extent over the last N_R measurements R_min < R_thr")
    n_valid: int = Field(ge=0, description="squared-residual arrays currently in the window")
    n_min: int = Field(ge=0, description="N_min, cell measurements")
    n_max: int = Field(ge=1, description="N_max, cell measurements")
    n_measurements: int = Field(ge=0, description="cell-rate measurements processed since the last reset")
    window_span_s: float = Field(ge=0.0, description="time between the oldest and newest measurement in the window, s")
    f_min_per_n_m2: float | None = Field(default=None, ge=0.0, description="F_min / N_valid, m^2")
    l_zk_m2: float = Field(ge=0.0, description="correction-zone parameter L_zk, m^2")
    c2_threshold_m2: float = Field(ge=0.0, description="mu_F * L_zk, m^2")
    d_max_cells: float | None = Field(default=None, ge=0.0, description="radius of the near-minimum set, cells")
    d_thr_cells: float | None = Field(default=None, ge=0.0, description="C3 threshold mu1 + mu2*phi, cells")
    r_min_cells: int | None = Field(default=None, ge=0, description="argmin bounding-box extent, cells")
    r_thr_cells: float = Field(ge=0.0, description="C4 threshold R_thr, cells")
    i_star: int | None = Field(default=None, description="longitudinal hypothesis offset of the minimum, cells")
    j_star: int | None = Field(default=None, description="transverse hypothesis offset of the minimum, cells")
    detail: str = Field(default="", max_length=256, description="free text for status verdicts")


#: the fix's horizontal block: corrected position along the map's axes x (longitudinal) and z (transverse)
MAP_HORIZONTAL = Layout(("x", "z"), ("m", "m"))
#: the vertical channel's block: corrections of the vertical speed and of the altitude (h_true = h_ins + dh)
VERTICAL_CORRECTION = Layout(("dvh", "dh"), ("m/s", "m"))


class TerrainFix(Message):
    """A reliable terrain fix: horizontal correction with covariance, and vertical-channel corrections.

    Valid at ``header.stamp_ns`` = time of the newest cell measurement in the window (``t_fix``).
    """

    schema_version: ClassVar[int] = 2

    dx_m: float = Field(description="longitudinal correction: x_true = x_ins + dx, m")
    dz_m: float = Field(description="transverse correction: z_true = z_ins + dz, m")
    estimate: GaussianEstimate = block_field(MAP_HORIZONTAL, "corrected horizontal position at t_fix")
    vertical: GaussianEstimate = block_field(VERTICAL_CORRECTION, "vertical corrections of the winning filter")
    h_corr_m: float = Field(description="corrected altitude at t_fix, m")
    vh_corr_mps: float | None = Field(default=None, description="corrected vertical speed (if the INS gives one), m/s")
    refined: bool = Field(description="the sub-cell refining search was accepted")
    cov_degenerate: bool = Field(description="the conservative fallback covariance was used (digest §2.6)")
    i_star: int = Field(description="longitudinal hypothesis offset of the minimum, cells")
    j_star: int = Field(description="transverse hypothesis offset of the minimum, cells")
    verdict: TerrainVerdict

    @model_validator(mode="after")
    def _shapes(self) -> TerrainFix:
        check_blocks(self)
        if not self.verdict.valid:
            raise ValueError("a TerrainFix needs a valid verdict")
        return self
