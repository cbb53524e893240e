"""One valid example of each terrain-navigation model (digest 001), for the contract tests."""

from __future__ import annotations

from schemas import Header, Message
from schemas.estimate import GaussianEstimate
from schemas.terrain_nav import TerrainFix, TerrainVerdict

H = Header(stamp_ns=1_700_000_017_500_000_000, frame_id="map", source="terrain_nav/1", seq=7)

VERDICT = TerrainVerdict(
    header=H,
    state="FIX",
    valid=True,
    c1_enough_data=True,
    c2_fit=True,
    c3_unique=True,
    c4_stable=True,
    n_valid=27,
    n_min=24,
    n_max=64,
    n_measurements=28,
    window_span_s=17.1,
    f_min_per_n_m2=21.5,
    l_zk_m2=163.2,
    c2_threshold_m2=81.6,
    d_max_cells=1.0,
    d_thr_cells=1.92,
    r_min_cells=0,
    r_thr_cells=1.0,
    i_star=-12,
    j_star=7,
)

EXAMPLES: dict[str, Message] = {
    "TerrainVerdict": VERDICT,
    "TerrainFix": TerrainFix(
        header=H,
        dx_m=-1498.2,
        dz_m=861.7,
        estimate=GaussianEstimate(
            frame="map",
            components=["x", "z"],
            units=["m", "m"],
            mean=[10_250.5, 9_611.9],
            covariance=[[1900.0, 35.0], [35.0, 2100.0]],
        ),
        vertical=GaussianEstimate(
            frame="map",
            components=["dvh", "dh"],
            units=["m/s", "m"],
            mean=[0.41, -43.2],
            covariance=[[0.02, 0.05], [0.05, 4.1]],
        ),
        h_corr_m=1712.4,
        vh_corr_mps=0.02,
        refined=False,
        cov_degenerate=False,
        i_star=-12,
        j_star=7,
        verdict=VERDICT,
    ),
}
