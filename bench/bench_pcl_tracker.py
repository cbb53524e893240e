"""PCL tracker: per-scan processing time (1, 10, 100 targets, with and without clutter) and UT cost per track.

Times are CPU time of this process (``time.process_time``), not wall time, so other load on a shared
machine inflates them less. Per-scan time is the CPU time of ``PclTracker.step`` (validation, prediction,
gating, GNN, updates, initiation and building the validated ``PclScanReport``), median over the scans
after the tracks are established. The UT cost per track and scan is the transform work the tracker does
for one track in one scan: the 12-point inverse UT of the prediction (gating; reused as the output when
coasting), the 12-point UT of the filtered state (bistatic output) and the 6-point UT of its associated
plot, measured for a lone track and per track for 100 tracks batched as the core does.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from services.pcl_tracker.core import PclTracker
from services.pcl_tracker.filter import bistatic_image, convert_plots
from services.pcl_tracker.simulation import ClutterSpec, many_target_scenario, paper_scenario, simulate

from .report import emit

N_SCANS = 25
WARMUP_SCANS = 8
CLUTTER_PER_SCAN = 20.0


def per_scan_ms(n_targets: int, clutter: bool, seed: int = 1) -> tuple[float, float, int]:
    """Median and 90th-percentile per-scan time (ms) and the mean number of live tracks measured."""
    rate = CLUTTER_PER_SCAN if clutter else 0.0
    if n_targets == 1:
        sc = paper_scenario(n_scans=N_SCANS, clutter=ClutterSpec(rate_per_scan=rate))
        cfg = sc.tracker_config()
    else:
        sc = many_target_scenario(
            n_targets, n_scans=N_SCANS, clutter=ClutterSpec(rate_per_scan=rate, rb_range_m=(0.0, 150_000.0))
        )
        cfg = sc.tracker_config(q_accel_var_m2s4=10.0, confirm_M=3, confirm_N=4)
    run = simulate(sc, np.random.default_rng(seed))
    trk = PclTracker(cfg)
    times: list[float] = []
    live: list[int] = []
    for k, scan in enumerate(run.scans):
        t0 = time.process_time()
        reps = trk.step(scan)
        dt = time.process_time() - t0
        if k >= WARMUP_SCANS:
            times.append(dt * 1e3)
            live.append(sum(r.n_tentative + r.n_confirmed for r in reps))
    times.sort()
    return statistics.median(times), times[int(0.9 * (len(times) - 1))], round(float(np.mean(live)))


def ut_cost_us(batch: int, repeats: int) -> float:
    """Transform cost per track and scan (µs) when ``batch`` tracks are processed together."""
    rng = np.random.default_rng(3)
    tx = np.array([8000.0, 0.0, 300.0])
    x = np.column_stack(
        [rng.uniform(5e3, 5e4, (batch, 2)), rng.uniform(500, 5000, batch), rng.normal(0, 150, (batch, 3))]
    )
    A = rng.normal(size=(batch, 6, 6))
    P = A @ np.swapaxes(A, 1, 2) + np.eye(6) * 100.0
    z3 = np.column_stack([rng.uniform(5e3, 5e4, batch), rng.uniform(-3, 3, batch), rng.uniform(0.01, 0.3, batch)])
    s3 = np.tile([200.0, np.radians(0.5), np.radians(0.5)], (batch, 1))
    best = float("inf")
    for _ in range(3):
        t0 = time.process_time()
        for _ in range(repeats):
            bistatic_image(x, P, tx)
            bistatic_image(x, P, tx)
            convert_plots(z3, s3, tx)
        best = min(best, (time.process_time() - t0) / repeats / batch * 1e6)
    return best


def main() -> None:
    rows = []
    figures: dict[str, object] = {}
    for n in (1, 10, 100):
        for clutter in (False, True):
            med, p90, live = per_scan_ms(n, clutter)
            label = f"{n} targets, {'clutter 20/scan' if clutter else 'no clutter'}"
            rows.append((label, live, med, p90))
            figures[f"scan_ms_{n}_targets_{'clutter' if clutter else 'clean'}"] = {
                "median_ms": round(med, 3),
                "p90_ms": round(p90, 3),
                "live_tracks": live,
            }
    ut1 = ut_cost_us(1, 1000)
    ut100 = ut_cost_us(100, 100)
    rows.append(("UT per track per scan, unbatched (µs)", 1, ut1, ""))
    rows.append(("UT per track per scan, 100 tracks batched (µs)", 100, ut100, ""))
    figures["ut_us_per_track_scan"] = {"unbatched": round(ut1, 2), "batched_100": round(ut100, 2)}
    med = {k: v["median_ms"] for k, v in figures.items() if k.startswith("scan_ms")}  # type: ignore[index]
    figures["ratios"] = {
        "clutter_over_clean_1": round(med["scan_ms_1_targets_clutter"] / med["scan_ms_1_targets_clean"], 2),
        "clutter_over_clean_100": round(med["scan_ms_100_targets_clutter"] / med["scan_ms_100_targets_clean"], 2),
        "t100_over_t1_clean": round(med["scan_ms_100_targets_clean"] / med["scan_ms_1_targets_clean"], 1),
        "ut_unbatched_over_batched": round(ut1 / ut100, 1),
    }
    emit("pcl_tracker", ["case", "live tracks", "median CPU ms (µs for UT)", "p90 CPU ms"], rows, figures)


if __name__ == "__main__":
    main()
