"""One valid example of every PCL tracker model (contract tests), built by hand, not by the core."""

from __future__ import annotations

from schemas import Header, Message
from schemas.estimate import GaussianEstimate
from schemas.pcl_tracker import PclScanReport, PclTrackReport

H = Header(stamp_ns=1_700_000_003_000_000_000, frame_id="pcl_enu", source="pcl_tracker/rx1", seq=7)
COV6 = [[float(i == j) * (100.0 if i < 3 else 4.0) for j in range(6)] for i in range(6)]
COV4 = [[40_000.0, 0.0, 0.0, 0.0], [0.0, 0.25, 0.0, 0.0], [0.0, 0.0, 0.25, 0.0], [0.0, 0.0, 0.0, 25.0]]


def enu(mean: list[float]) -> GaussianEstimate:
    comps, units = ["x", "y", "z", "vx", "vy", "vz"], ["m", "m", "m", "m/s", "m/s", "m/s"]
    return GaussianEstimate(frame="pcl_enu", components=comps, units=units, mean=mean, covariance=COV6)


def bistatic(mean: list[float]) -> GaussianEstimate:
    comps, units = ["r_b", "az", "el", "v_b"], ["m", "deg", "deg", "m/s"]
    return GaussianEstimate(frame="bistatic/rx1/tx-fm-98.1", components=comps, units=units, mean=mean, covariance=COV4)


LIVE = PclTrackReport(
    track_id=3,
    status="CONFIRMED",
    scan_id=12,
    t_s=33.0,
    estimate=enu([3178.2, 3548.5, 1000.0, -194.06, -48.38, 0.0]),
    bistatic=bistatic([2889.4, 41.85, 11.86, -35.23]),
    associated_plot_id="p0001",
    nis=3.2,
    n_plots_in_gate=1,
    hits=12,
    consecutive_misses=0,
    age_scans=10,
    created_scan_id=2,
    updated=True,
    model_probabilities=[0.91, 0.05, 0.03, 0.01],
)
DROPPED = PclTrackReport(
    track_id=4,
    status="DROPPED",
    scan_id=12,
    t_s=33.0,
    estimate=enu([10_000.0, -2_000.0, 500.0, 100.0, 0.0, 0.0]),
    bistatic=bistatic([5000.0, 101.3, 2.8, 150.0]),
    hits=2,
    consecutive_misses=3,
    age_scans=3,
    created_scan_id=9,
    coasted=True,
    drop_reason="K_misses",
    flags=["coasted"],
)

EXAMPLES: dict[str, Message] = {
    "PclScanReport": PclScanReport(
        header=H,
        receiver_id="rx1",
        illuminator_id="tx-fm-98.1",
        scan_id=12,
        t_s=33.0,
        tracks=[LIVE, DROPPED],
        n_plots_in=21,
        n_plots_rejected={"out_of_range": 1},
        n_plots_flagged={"sigma_defaulted": 2},
        n_associated=1,
        n_initiated=0,
        n_candidates=17,
        n_confirmed=1,
        n_dropped=1,
        mean_nis=3.2,
        gate_d2=13.28,
        flags=["sigma_defaulted"],
    ),
}
