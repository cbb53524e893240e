"""Parameters of the terrain navigator with the digest's defaults (digest 001 §6).

Provenance tags in the descriptions: [P] stated in the paper, [R] reconstructed from a garbled OCR,
[D] a design default of the digest. Every [R]/[D] item is a parameter here so it can be changed.
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

#: the values a preset gives to the parameters it sets (any of them can still be given explicitly)
PRESETS: dict[str, dict[str, Any]] = {
    # the digest's configuration (§6), every acceptance test of §4 is run with it
    "paper": {},
    # the paper's algorithm with the corrections of docs/terrain_nav.md: C3's near-minimum region floored at the
    # residual level the model expects ("False fixes on coarse and partly flat maps"), the slope term of the
    # vertical channel ("The vertical channel over smooth terrain") and the sub-cell refinement of §2.6 with a
    # sigma floor of 0.3 cell (one-cell slips on low relief and coarse maps, "Terrain families"); not c3_evidence,
    # which gives false fixes on the coarse partly flat map ("Rough terrain: availability", issue 16)
    "robust": {
        "c3_floor": 0.5,
        "vertical_slope_term": True,
        "refine": True,
        "refine_sigma_floor_cells": 0.3,
        "refine_vertical": True,
    },
}


class TerrainNavConfig(BaseModel):
    """Configuration of :class:`services.terrain_nav.core.TerrainNavigator` (and the base algorithm).

    ``preset`` fills the parameters it names (``PRESETS``) unless they are given explicitly: ``robust`` (the
    default) adds to the digest's algorithm the corrections against false fixes over inhomogeneous (partly flat,
    coarse) maps and the slope term of the vertical channel; ``paper`` is the digest's configuration (§6), the
    one every acceptance test of §4 runs (docs/terrain_nav.md, "The default preset").
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    preset: Literal["paper", "robust"] = Field(default="robust", description="robust (default) or paper (digest §6)")

    @model_validator(mode="before")
    @classmethod
    def _apply_preset(cls, data: Any) -> Any:
        if isinstance(data, dict):
            preset = data.get("preset", "robust")
            if preset in PRESETS:
                return {**PRESETS[preset], **data}
        return data

    # --- hypothesis grid (§2.1) -------------------------------------------------------------------------
    M_x: int = Field(default=25, ge=1, le=500, description="longitudinal search half-width, cells [D]")
    M_z: int = Field(default=25, ge=1, le=500, description="transverse search half-width, cells [D]")

    # --- window and grouping (§2.3, §2.9) ---------------------------------------------------------------
    N_min: int = Field(default=24, ge=1, description="C1 threshold, cell measurements [D]")
    N_max: int = Field(default=64, ge=2, description="window length, cell measurements [D]")
    derive_n_limits: bool = Field(default=False, description="derive N_min/N_max from the map at start (§2.12) [D]")
    N_p: int = Field(default=4, ge=1, le=64, description="group size: measurements per evaluation [D]")
    N_s: int = Field(default=8, ge=1, le=256, description="segment size of the sliding window [D]")
    N_R: int = Field(default=8, ge=1, description="stability history for C4, measurements [D]")
    window_recompute_segments: int = Field(
        default=50, ge=1, description="recompute F from the segment sums after this many closed segments [D]"
    )

    # --- reliability conditions (§2.5) -----------------------------------------------------------------
    c1_strict: bool = Field(default=True, description="C1 as N_valid > N_min (True) or >= (False) [R]")
    mu_F: float = Field(default=0.5, gt=0.0, description="C2 factor on L_zk [R]/[D]")  # noqa: N815 - digest symbol
    L_zk_source: Literal["D1", "sigma_t2"] = Field(default="D1", description="L_zk = D1 or terrain variance [R]")
    L_zk_m2: float | None = Field(default=None, gt=0.0, description="fixed L_zk, m^2 (None: from the map) [D]")
    mu1: float = Field(default=1.5, ge=0.0, description="C3 constant term, cells [D]")
    mu2: float = Field(default=1.0, ge=0.0, description="C3 coefficient of phi(N_valid), cells [D]")
    mu3: float = Field(default=1.5, ge=0.0, description="C3 near-minimum region F <= F_min*(1+mu3) [D]")
    phi: Literal["n_over_nmax", "nmax_over_n", "linear_min_max"] = Field(
        default="n_over_nmax", description="phi(N) of C3: N/N_max, N_max/N or (N-N_min)/(N_max-N_min) [R]"
    )
    R_thr: float = Field(default=1.0, ge=0.0, description="C4 threshold on the argmin extent, cells [R]")
    R_strict: bool = Field(default=True, description="C4 as R_min < R_thr (True) or <= (False) [R]")
    c3_floor: float | None = Field(
        default=None,
        gt=0.0,
        le=1.0,
        description="C3 region F <= F_min + mu3*max(F_min, c3_floor * sum of the window's expected e^2 S_k) "
        "instead of F <= F_min*(1+mu3): a minimum that fits far better than the noise the model expects cannot "
        "shrink the region below that noise (None: the paper's form) [robust]",
    )

    c3_evidence: float | None = Field(
        default=None,
        gt=0.0,
        description="cap the C3 region's gap F - F_min at 2*c3_evidence*s (s: the window's median S_k or F_min/N, "
        "the larger): a hypothesis whose likelihood is below exp(-c3_evidence) times the argmin's does not count, "
        "however close F/F_min is to 1, if it lies farther than c3_evidence_beyond_cells from the argmin (distant "
        "minima on rough terrain, issue 16; None: the paper's form; not in robust: false fixes on the coarse partly "
        "flat map) [D]",
    )
    c3_evidence_beyond_cells: float = Field(
        default=4.0, ge=0.0, description="c3_evidence applies to cells farther than this from the argmin, cells"
    )

    # --- vertical Kalman filter (§1.4, §1.7, §2.2) -----------------------------------------------------
    phi31: Literal["exact", "euler"] = Field(default="exact", description="row 3 of Phi: T^2/2 or 0 [R]")
    sigma_v_m: float = Field(default=2.0, gt=0.0, description="radio-altimeter white noise per raw sample, m [D]")
    sigma_map_m: float = Field(default=3.0, ge=0.0, description="DEM error per cell, m [D]")
    c_q: float = Field(default=0.3, ge=0.0, description="quantisation term c_q*D1 in R_k [D]")
    q_a: float = Field(default=1e-6, ge=0.0, description="spectral density of the da random walk, (m/s^2)^2/s [D]")
    q_h: float = Field(default=0.0, ge=0.0, description="optional dh process noise density, m^2/s [D]")
    P0_sigma_a: float = Field(default=0.01, gt=0.0, description="initial sigma of da, m/s^2 [D]")
    P0_sigma_V: float = Field(default=1.0, gt=0.0, description="initial sigma of dV, m/s [D]")
    P0_sigma_h: float = Field(default=100.0, gt=0.0, description="initial sigma of dh, m [D]")
    vertical_slope_term: bool = Field(
        default=False,
        description="a fix's dh and P_hh at the fix's position: the dh of a hypothesis is that of the cell "
        "centres, off by g.e where the aircraft is e from them (g the window's mean map slope at the fix's "
        "cells); report P_hh + g^T Cov_xz g and, for a refined fix moved by d from the centres, dh + g.d "
        "(the paper: neither) [robust]",
    )
    normalize_by_S: bool = Field(  # noqa: N815 - the digest's option name
        default=False, description="accumulate nu^2 * R_k/S_k instead of nu^2 (paper: raw nu^2) [D]"
    )
    pre_gate_k: float | None = Field(
        default=None,
        gt=0.0,
        description="optional spike gate once C1 holds: skip a measurement whose innovation at the argmin of F "
        "exceeds k*sqrt(S_k) [D]",
    )

    # --- input handling (§5.1, §5.6, §2.7) -------------------------------------------------------------
    altitude_source: Literal["ins", "baro"] = Field(default="ins", description="h_ins from INS or baro altitude")
    ins_max_gap_s: float = Field(default=0.2, gt=0.0, description="max distance of a bracketing INS sample, s [D]")
    baro_max_gap_s: float = Field(default=0.5, gt=0.0, description="max distance of a bracketing baro sample, s [D]")
    kappa_gap: float = Field(default=1.5, gt=0.0, description="gap if dt > kappa_gap * cell/|V_h| [D]")
    T_reset_s: float | None = Field(
        default=None, gt=0.0, description="reset the window after a gap longer than this, s (None: N_max cells) [D]"
    )
    T_cell_max_s: float = Field(default=5.0, gt=0.0, description="emit a cell measurement after this long, s [D]")
    min_speed_mps: float = Field(default=5.0, gt=0.0, description="ground speed floor for gap timing, m/s [D]")
    out_of_zone_period_s: float = Field(default=1.0, ge=0.0, description="at most one OUT_OF_ZONE verdict per this, s")

    # --- output (§2.6) -------------------------------------------------------------------------------------
    refine: bool = Field(default=False, description="sub-cell refining search after a valid fix [P idea, D method]")
    refine_step_cells: float = Field(default=0.125, gt=0.0, le=0.5, description="refinement step, cells [D]")
    refine_radius_cells: float = Field(default=1.0, gt=0.0, le=3.0, description="refinement half-width, cells [D]")
    refine_sigma_floor_cells: float = Field(
        default=0.1, ge=0.0, description="floor of each sigma of a refined fix, cells (simulation rms 0.09) [D]"
    )
    refine_vertical: bool = Field(
        default=False,
        description="a refined fix takes dh, dV and their covariance from the refinement's replay at the refined "
        "offset (bilinear map reads at the aircraft's positions) instead of the grid filter (cell-centre reads, "
        "whose quantisation error is correlated along the track over smooth terrain); the slope term then adds "
        "g^T Cov_xz g only (issue 16) [robust]",
    )
    cell_centre_conversion: bool = Field(
        default=True, description="add the mean (cell centre - INS) term to i*cell, j*cell (§2.6) [D]"
    )
    frame_id: str = Field(default="map", max_length=128, description="frame of the output positions")

    # --- base algorithm (§2.13) and N-limit derivation (§2.12) ----------------------------------------
    nominal_speed_mps: float = Field(default=200.0, gt=0.0, description="V used to convert cell counts, m/s [D]")
    base_sample_rate_hz: float = Field(default=20.0, gt=0.0, description="raw sample rate of the base mode, Hz")
    sigma_Vh_expected_mps: float = Field(  # noqa: N815 - sigma_Vh of §2.12
        default=0.3, gt=0.0, description="expected horizontal velocity error, m/s [D]"
    )
    derive_profiles: int = Field(default=200, ge=10, description="profiles per N in the N_min derivation [D]")
    derive_success: float = Field(default=0.99, gt=0.0, le=1.0, description="success share defining N_min [D]")
    derive_seed: int = Field(default=0, description="seed of the N_min derivation")

    @model_validator(mode="after")
    def _consistent(self) -> TerrainNavConfig:
        if not self.derive_n_limits and self.N_max < self.N_min + 1:
            raise ValueError("N_max must exceed N_min")
        return self

    # --- derived quantities ---------------------------------------------------------------------------
    @property
    def P0(self) -> list[float]:
        """Diagonal of the initial vertical covariance (da, dV, dh), SI units squared."""
        return [self.P0_sigma_a**2, self.P0_sigma_V**2, self.P0_sigma_h**2]

    def base_samples_per_cell(self, cell_m: float) -> float:
        """Raw samples per crossed cell in the base mode, f_s * cell / V (12.5 for the defaults)."""
        return self.base_sample_rate_hz * cell_m / self.nominal_speed_mps

    def base_n_limits(self, cell_m: float) -> tuple[int, int]:
        """N_min and N_max of the base mode as sample counts covering the same profile length (§2.13)."""
        k = self.base_samples_per_cell(cell_m)
        return math.ceil(self.N_min * k), math.ceil(self.N_max * k)
