"""What one evaluation of the recurrent search yields: the verdict record and, when valid, the fix quantities.

Both algorithm variants (:mod:`.modified_algorithm`, :mod:`.base_algorithm`) produce these plain records; the
navigator (:mod:`.core`) turns them into :class:`~schemas.terrain_nav.TerrainVerdict` and
:class:`~schemas.terrain_nav.TerrainFix` messages.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .geometry import F64


@dataclass
class FixData:
    """Fix quantities of a valid evaluation (plain numbers; converted to :class:`TerrainFix` by ``step``)."""

    dx_m: float
    dz_m: float
    x_corr_m: float
    z_corr_m: float
    cov_xz_m2: F64
    dh_m: float
    dvh_mps: float
    h_corr_m: float
    vh_corr_mps: float | None
    cov_vert: F64  # [[P_VV, P_Vh], [P_hV, P_hh]]
    refined: bool
    cov_degenerate: bool


@dataclass
class Evaluation:
    """One evaluation of C1-C4 (or a status event when ``state`` is OUT_OF_ZONE, GAP or RESET)."""

    t: float
    state: str
    valid: bool = False
    c1: bool = False
    c2: bool = False
    c3: bool = False
    c4: bool = False
    n_valid: int = 0
    n_measurements: int = 0
    window_span_s: float = 0.0
    f_min_per_n: float | None = None
    d_max: float | None = None
    d_thr: float | None = None
    r_min: int | None = None
    i_star: int | None = None
    j_star: int | None = None
    detail: str = ""
    fix: FixData | None = None

    @property
    def is_status(self) -> bool:
        return self.state in ("OUT_OF_ZONE", "GAP", "RESET")


def verdict_state(c1: bool, c2: bool, c3: bool, c4: bool) -> str:
    """The state word: FIX if all hold, else the first failing condition in the order C1, C2, C3, C4."""
    if not c1:
        return "ACQUIRING"
    if not c2:
        return "NO_FIX_FIT"
    if not c3:
        return "NO_FIX_AMBIGUOUS"
    if not c4:
        return "NO_FIX_UNSTABLE"
    return "FIX"


def finite(*values: float | None) -> bool:
    return all(v is None or math.isfinite(v) for v in values)
