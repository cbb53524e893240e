"""PCL tracker core: scan processing time against targets and clutter, and the UT cost per track.

The issue's grid: 10, 100 and 1,000 targets (the many-target layout of ``simulation.many_target_scenario``:
15-60 km, half of them turning, P_d = 0.95) with 0, 100 and 1,000 clutter plots per scan (uniform over
r_b in [0, 150] km), tracker q = 10 m²/s⁴ and M/N = 3/4 (one CV model: ``preset: paper`` with those two
changes, the former rx1-dvbt tuning); the 100-target rows are repeated with the default configuration
(``preset: robust``: IMM over four CV models, four inverse UTs per track and scan). Each case is run twice:

* ``full``: limits raised (``max_plots_per_scan``, ``max_tentative_tracks``, ``max_confirmed_tracks``) so
  every plot of every scan goes through gating, assignment, conversion and 2/L initiation; with 1,000
  clutter plots the ring gate then passes a few hundred false pairs per scan, so several hundred
  tentative tracks are alive and dropped at every scan. This is the worst case, and the target
  (100 targets with 1,000 clutter plots per scan in under 50 ms) is checked on it;
* ``default``: the digest's default limits; a scan of more than ``max_plots_per_scan`` = 500 plots is a
  clutter burst (association with the existing tracks only, no initiation), and at most
  ``max_confirmed_tracks`` = 500 tracks are confirmed. So that there are tracks to associate, the clutter
  starts after the warm-up scans in this variant; with 1,000 targets the target plots alone exceed 500 per
  scan, so no track is ever started: the default limits are sized for a few hundred targets.

Time is CPU time of ``PclTracker.step`` (``time.process_time``: validation, prediction, inverse UT,
gating, GNN, updates, initiation and the report with every track), the median (and 90th percentile) over
the scans after the first eight. The scans are stored msgpack-encoded and decoded outside the timed
region (as the service receives them), and the cyclic garbage collector's generations are frozen after
set-up, as the service does at start (``service.build``). Also the paper's single target (with and
without the E5 clutter) and the UT cost per track and scan, alone and batched over 100 tracks.
"""

from __future__ import annotations

import gc
import statistics
import time

import numpy as np

from schemas.radar import BistaticScan
from services.pcl_tracker.config import PclTrackerConfig
from services.pcl_tracker.core import PclTracker
from services.pcl_tracker.filter import bistatic_image, convert_plots
from services.pcl_tracker.simulation import ClutterSpec, PclScenario, many_target_scenario, paper_scenario, simulate
from shared import codec

from .report import emit

N_SCANS = 20
WARMUP_SCANS = 8
TARGETS = (10, 100, 1000)
CLUTTER = (0, 100, 1000)
TARGET_MS = 50.0


def time_scans(
    sc: PclScenario, cfg: PclTrackerConfig, seed: int = 1, clutter_after_warmup: bool = False
) -> tuple[float, float, float]:
    """Median and p90 CPU ms per scan after the warm-up, and the mean number of live tracks."""
    run = simulate(sc, np.random.default_rng(seed))
    scans = run.scans
    if clutter_after_warmup:
        scans = [
            s.model_copy(update={"plots": [p for p in s.plots if run.plot_origin[k][p.plot_id] >= 0]})
            if k < WARMUP_SCANS
            else s
            for k, s in enumerate(scans)
        ]
    blobs = [codec.encode(s) for s in scans]
    trk = PclTracker(cfg)
    gc.collect()
    gc.freeze()
    times: list[float] = []
    live: list[int] = []
    try:
        for k, blob in enumerate(blobs):
            scan = codec.decode_as(BistaticScan, blob)
            assert isinstance(scan, BistaticScan)
            t0 = time.process_time()
            reps = trk.step(scan)
            dt = time.process_time() - t0
            if k >= WARMUP_SCANS:
                times.append(dt * 1e3)
                live.append(sum(r.n_tentative + r.n_confirmed for r in reps))
            del reps
    finally:
        gc.unfreeze()
    times.sort()
    return statistics.median(times), times[int(0.9 * (len(times) - 1))], float(np.mean(live))


def grid_case(n_targets: int, clutter: float, full: bool, preset: str = "paper") -> tuple[float, float, float]:
    sc = many_target_scenario(
        n_targets, n_scans=N_SCANS, clutter=ClutterSpec(rate_per_scan=clutter, rb_range_m=(0.0, 150_000.0))
    )
    if preset == "paper":
        cfg = sc.tracker_config(preset="paper", q_accel_var_m2s4=10.0, confirm_M=3, confirm_N=4)
    else:
        cfg = sc.tracker_config()
    if full:
        cfg = cfg.with_limits(
            max_plots_per_scan=1_000_000, max_tentative_tracks=1_000_000, max_confirmed_tracks=100_000
        )
        return time_scans(sc, cfg)
    return time_scans(sc, cfg, clutter_after_warmup=True)


def ut_cost_us(batch: int, repeats: int) -> float:
    """Transform cost per track and scan (µs) when ``batch`` tracks are processed together: the 12-point
    inverse UT of the prediction, the 12-point UT of the filtered state and the 6-point UT of its plot."""
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
    rows: list[tuple[object, ...]] = []
    figures: dict[str, object] = {"target_ms": TARGET_MS, "scans_timed": N_SCANS - WARMUP_SCANS}
    grid: dict[str, object] = {}
    for n in TARGETS:
        for c in CLUTTER:
            med, p90, live = grid_case(n, c, full=True)
            dmed, _, dlive = grid_case(n, c, full=False)
            rows.append(
                (
                    f"{n} targets, {c} clutter/scan",
                    round(live),
                    round(med, 1),
                    round(p90, 1),
                    round(dlive),
                    round(dmed, 1),
                )
            )
            grid[f"{n}x{c}"] = {
                "targets": n,
                "clutter_per_scan": c,
                "full": {"median_ms": round(med, 2), "p90_ms": round(p90, 2), "live_tracks": round(live, 1)},
                "default_limits": {"median_ms": round(dmed, 2), "live_tracks": round(dlive, 1)},
            }
    for c in CLUTTER:
        med, p90, live = grid_case(100, c, full=True, preset="robust")
        dmed, _, dlive = grid_case(100, c, full=False, preset="robust")
        rows.append(
            (
                f"100 targets, {c} clutter/scan, default (IMM)",
                round(live),
                round(med, 1),
                round(p90, 1),
                round(dlive),
                round(dmed, 1),
            )
        )
        grid[f"100x{c}/default"] = {
            "full": {"median_ms": round(med, 2), "p90_ms": round(p90, 2), "live_tracks": round(live, 1)},
            "default_limits": {"median_ms": round(dmed, 2), "live_tracks": round(dlive, 1)},
        }
    figures["grid"] = grid
    full_100_1000 = grid["100x1000"]["full"]  # type: ignore[index]
    figures["target_met_100_targets_1000_clutter"] = full_100_1000["median_ms"] < TARGET_MS  # type: ignore[index]
    for clutter in (0.0, 20.0):
        sc = paper_scenario(n_scans=N_SCANS + 5, clutter=ClutterSpec(rate_per_scan=clutter))
        med, p90, live = time_scans(sc, sc.tracker_config(preset="paper"))
        label = f"paper target (1), {'E5 clutter 20/scan' if clutter else 'no clutter'}, M = 0"
        rows.append((label, round(live), round(med, 2), round(p90, 2), "", ""))
        figures[f"paper_{'clutter' if clutter else 'clean'}"] = {"median_ms": round(med, 3), "p90_ms": round(p90, 3)}
    ut1 = ut_cost_us(1, 1000)
    ut100 = ut_cost_us(100, 100)
    rows.append(("UT per track per scan, one track alone (µs)", 1, round(ut1, 1), "", "", ""))
    rows.append(("UT per track per scan, 100 tracks batched (µs)", 100, round(ut100, 1), "", "", ""))
    figures["ut_us_per_track_scan"] = {"unbatched": round(ut1, 2), "batched_100": round(ut100, 2)}
    emit(
        "pcl_tracker",
        ["case", "live tracks", "median CPU ms", "p90 CPU ms", "live (default limits)", "median ms (default limits)"],
        rows,
        figures,
    )


if __name__ == "__main__":
    main()
