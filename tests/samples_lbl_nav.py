"""One valid example of each model of ``schemas/lbl_nav.py`` (contract tests merge this into their samples)."""

from __future__ import annotations

from schemas import Header, Hypothesis, Message
from schemas.lbl_nav import LblEvent, LblFix

H = Header(stamp_ns=1_700_000_000_123_456_789, frame_id="local_en_depth", source="lbl_nav/auv1", seq=7)
COV3 = [[25.0, 3.0, 0.0], [3.0, 16.0, 0.0], [0.0, 0.0, 0.0]]
COV6 = [[float(i == j) * (1.0 + i) for j in range(6)] for i in range(6)]

EXAMPLES: dict[str, Message] = {
    "LblFix": LblFix(
        header=H,
        platform="auv1",
        status="TRACKING",
        valid=True,
        position_m=[451.5, 610.25, 30.0],
        position_cov_m2=COV3,
        hypotheses=[
            Hypothesis(hypothesis_id=2, position_m=[451.5, 610.25, 30.0], position_cov_m2=COV3, probability=1.0)
        ],
        log10_ratio=None,
        log10_threshold=4.0,
        accepted_hypothesis=2,
        hypothesis_source="resolved",
        launch_stamp_ns=1_700_000_000_000_000_000,
        resolved_stamp_ns=1_700_000_005_000_000_000,
        buffered_epochs=360,
        processed_buffered=120,
        saved_progress=1.0 / 3.0,
        catching_up=True,
        dc_mps=0.5,
        dK_rad=-0.01,
        dU_north_mps=0.05,
        dU_east_mps=-0.02,
        sigma_dc_mps=2.9,
        sigma_dK_rad=0.08,
        sigma_dU_north_mps=0.2,
        sigma_dU_east_mps=0.21,
        state_cov=COV6,
        ranges_used=1,
        ranges_rejected=0,
        buffer_dropped=3,
        degraded=False,
    ),
    "LblEvent": LblEvent(
        header=H,
        platform="auv1",
        kind="launch",
        reason="",
        detail="n0=2 N=360 hypotheses=2",
        log10_ratio=0.0,
        grid_nodes=12,
        cluster_sizes=[6, 6],
        centres_m=[[-441.1, 607.1], [441.1, 607.1]],
    ),
}
