"""One valid example of each model of ``schemas/lbl_nav.py`` (contract tests merge this into their samples)."""

from __future__ import annotations

from schemas import Header, Hypothesis, Message
from schemas.estimate import GaussianEstimate
from schemas.lbl_nav import LblEvent, LblFix

H = Header(stamp_ns=1_700_000_000_123_456_789, frame_id="local_en_depth", source="lbl_nav/auv1", seq=7)
COV3 = [[25.0, 3.0, 0.0], [3.0, 16.0, 0.0], [0.0, 0.0, 0.0]]
COV6 = [[float(i == j) * (1.0 + i) for j in range(6)] for i in range(6)]
POS = GaussianEstimate(
    frame="local_en_depth",
    components=["x", "y", "z"],
    units=["m", "m", "m"],
    mean=[451.5, 610.25, 30.0],
    covariance=COV3,
)

EXAMPLES: dict[str, Message] = {
    "LblFix": LblFix(
        header=H,
        platform="auv1",
        status="TRACKING",
        valid=True,
        estimate=POS,
        hypotheses=[Hypothesis(hypothesis_id=2, estimate=POS, probability=1.0)],
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
        state=GaussianEstimate(
            frame="local_en_depth",
            components=["x", "y", "dc", "dK", "dU_north", "dU_east"],
            units=["m", "m", "m/s", "rad", "m/s", "m/s"],
            mean=[451.5, 610.25, 0.5, -0.01, 0.05, -0.02],
            covariance=COV6,
        ),
        sigma_dc_mps=2.9,
        sigma_dK_rad=0.08,
        sigma_dU_north_mps=0.2,
        sigma_dU_east_mps=0.21,
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
