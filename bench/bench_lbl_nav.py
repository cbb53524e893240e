"""Benchmark of the LBL estimator core (digest 000, sections 3.3 and 4.2 S5).

Figures (microseconds, medians over repetitions, all measured in this one run):

* per-epoch update time of one hypothesis with Delta N = 10 buffered epochs (n_s = 1, n_i = 2);
* launch time with two beacons (L = 12 grid nodes, 5 Gauss-Newton iterations, both hypotheses);
* the full core ``step`` cost per epoch while catching up (two hypotheses, validated outputs);
* the paper's comparison: the two-filter sequential scheme (KF + KF) against the single filter, as a time ratio
  for Delta N = 1, 2, 3, 5, 10, 30, 100 (paper: 157, 145, 138, 130, 131, 134, 133 %);
* S5: launch vs a Delta N = 100 step, and the ratio computation vs a Delta N = 1 step.

Times are CPU time of this process (``time.process_time_ns``), so that other load on a shared machine disturbs
them less than wall-clock time would. Run: ``python -m bench.bench_lbl_nav``. Prints a table and one JSON line.
Never asserted in tests.
"""

from __future__ import annotations

import json
import math
import statistics
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from services.lbl_nav import initiation
from services.lbl_nav.alternatives import TwoFilterScheme
from services.lbl_nav.config import LblNavConfig
from services.lbl_nav.core import LblNavCore
from services.lbl_nav.filter import BufferedEpoch, HypothesisBank, HypothesisFilter
from services.lbl_nav.models import DrInterval, MotionModel, RangeRow
from services.lbl_nav.offline import feed
from services.lbl_nav.simulation import s1_spec, simulate

B1, B2 = (0.0, 0.0, 100.0), (0.0, 1500.0, 100.0)


def _case(N: int, seed: int = 0) -> tuple[LblNavConfig, np.ndarray, np.ndarray, list[BufferedEpoch], DrInterval]:
    """A launch state and N buffered epochs with one range each (straight track at 5 m/s)."""
    rng = np.random.default_rng(seed)
    cfg = LblNavConfig()
    dr = DrInterval(1.0, -0.87, 4.92)
    p0 = np.array([450.0, 606.97])
    buf = []
    for k in range(-N, 0):
        p = p0 + k * np.array([-0.87, 4.92])
        y = math.sqrt(p[0] ** 2 + p[1] ** 2 + 70.0**2) + rng.normal(0, 11.0)
        buf.append(BufferedEpoch(k, k, dr, [RangeRow("s", k, k, "B1", y, *B1, 30.0, y / 1500.0)], 30.0))
    lr = []
    for bid, b in (("B1", B1), ("B2", B2)):
        y = math.sqrt((b[0] - p0[0]) ** 2 + (b[1] - p0[1]) ** 2 + 70.0**2)
        lr.append(initiation.LaunchRange(bid, *b, y, y / 1500.0))
    res = initiation.launch(lr, 30.0, cfg)
    c = res.candidates[1]
    return cfg, c.X0, c.P0, buf, dr


def _current_rows(k: int) -> list[RangeRow]:
    p = np.array([450.0, 606.97]) + k * np.array([-0.87, 4.92])
    rows = []
    for bid, b in (("B1", B1), ("B2", B2)):
        y = math.sqrt((b[0] - p[0]) ** 2 + (b[1] - p[1]) ** 2 + 70.0**2)
        rows.append(RangeRow("i", k, k, bid, y, *b, 30.0, y / 1500.0))
    return rows


def _median_us(fn: Callable[[], object], setup: Callable[[], object] | None, reps: int) -> float:
    times = []
    for _ in range(reps):
        arg = setup() if setup else None
        t0 = time.process_time_ns()
        fn() if arg is None else fn(arg)  # type: ignore[call-arg]
        times.append(time.process_time_ns() - t0)
    return statistics.median(times) / 1e3


def bench_single_vs_two_filters(dN: int, reps: int) -> tuple[float, float]:
    """One epoch step (Delta N buffered + 2 current ranges) of the single filter and of KF + KF, interleaved."""
    single, double = [], []
    rows = _current_rows(1)
    for r in range(reps):
        cfg, X0, P0, buf, dr = _case(dN + 1, seed=r)
        cfg = cfg.model_copy(update={"dN": dN})
        bank = HypothesisBank(cfg, MotionModel(cfg), [HypothesisFilter(1, X0, P0)], buf, dr)
        kk = TwoFilterScheme(cfg, X0, P0, list(buf), dr)
        t0 = time.process_time_ns()
        bank.epoch_step(dr, rows)
        t1 = time.process_time_ns()
        kk.epoch_step(dr, rows)
        t2 = time.process_time_ns()
        single.append(t1 - t0)
        double.append(t2 - t1)
    return statistics.median(single) / 1e3, statistics.median(double) / 1e3


def bench_epoch_dN10(reps: int) -> float:
    """Per-epoch update time of one hypothesis with Delta N = 10 over the 36 catch-up epochs of N = 360."""
    cfg, X0, P0, buf, dr = _case(360)
    times = []
    for _ in range(reps):
        bank = HypothesisBank(cfg, MotionModel(cfg), [HypothesisFilter(1, X0.copy(), P0.copy())], list(buf), dr)
        for i in range(1, 37):
            rows = _current_rows(i)
            t0 = time.process_time_ns()
            bank.epoch_step(dr, rows)
            times.append(time.process_time_ns() - t0)
    return statistics.median(times) / 1e3


def bench_launch(reps: int) -> float:
    cfg = LblNavConfig()
    lr = []
    for bid, b in (("B1", B1), ("B2", B2)):
        y = math.sqrt((b[0] - 450.0) ** 2 + (b[1] - 606.97) ** 2 + 70.0**2) + 3.0
        lr.append(initiation.LaunchRange(bid, *b, y, y / 1500.0))
    assert cfg.grid_nodes() == 12 and cfg.gn_iter == 5
    return _median_us(lambda: initiation.launch(lr, 30.0, cfg), None, reps)


def bench_ratio(reps: int) -> float:
    cfg, X0, P0, _, dr = _case(1)
    bank = HypothesisBank(
        cfg.model_copy(update={"ratio_threshold": 1e300}),
        MotionModel(cfg),
        [HypothesisFilter(1, X0, P0), HypothesisFilter(2, X0 + np.array([-900.0, 0, 0, 0, 0, 0]), P0)],
        [],
        dr,
    )
    us = _median_us(lambda: (bank.log_ratio(), bank.decide(), bank.probabilities()), None, reps)
    assert len(bank.hyps) == 2
    return us


def bench_core_epoch() -> float:
    """Full LblNavCore.step per epoch over t_0 .. t_0 + 36 s of the S1 replica (two hypotheses, validated outputs)."""
    sim = simulate(replace(s1_spec(), t_end_s=36.0), np.random.default_rng(3), 3)
    t0_ns = int(sim.stamps_ns[sim.i0])
    pre = [m for m in sim.messages if m.header.stamp_ns <= t0_ns]
    post = [m for m in sim.messages if m.header.stamp_ns > t0_ns]
    core = LblNavCore(LblNavConfig(ratio_threshold=1e300))  # keep both hypotheses alive for the measurement
    feed(core, pre)
    t = time.process_time_ns()
    feed(core, post)
    return (time.process_time_ns() - t) / 1e3 / 36.0


def main() -> int:
    started = time.perf_counter()
    launch_us = bench_launch(300)
    epoch_us = bench_epoch_dN10(8)
    core_us = bench_core_epoch()
    ratio_us = bench_ratio(2000)
    comparison = {}
    for dN, reps in ((1, 300), (2, 300), (3, 300), (5, 200), (10, 150), (30, 60), (100, 25)):
        s, d = bench_single_vs_two_filters(dN, reps)
        comparison[dN] = {"single_us": s, "kf_kf_us": d, "ratio_pct": 100.0 * d / s}
    paper = {1: 157, 2: 145, 3: 138, 5: 130, 10: 131, 30: 134, 100: 133}
    # linear fit of the single-filter step cost in Delta N (S5: about linear)
    xs = np.array(list(comparison))
    ys = np.array([comparison[k]["single_us"] for k in comparison])
    slope, intercept = np.polyfit(xs, ys, 1)
    r2 = 1.0 - float(np.sum((ys - (slope * xs + intercept)) ** 2) / np.sum((ys - ys.mean()) ** 2))

    print("LBL estimator core benchmark (microseconds, medians)")
    print(f"  epoch update, one hypothesis, dN = 10, n_s = 1, n_i = 2 : {epoch_us:10.1f}")
    print(f"  launch, two beacons, L = 12, 5 GN iterations           : {launch_us:10.1f}")
    print(f"  core step per epoch while catching up (2 hyps, outputs) : {core_us:10.1f}")
    print(f"  ratio + decision                                        : {ratio_us:10.1f}")
    print()
    print("  dN   single KF (us)   KF + KF (us)   KF+KF / KF (%)   paper (%)")
    for dN, c in comparison.items():
        print(f"  {dN:3d} {c['single_us']:14.1f} {c['kf_kf_us']:14.1f} {c['ratio_pct']:15.0f} {paper[dN]:11d}")
    print()
    print(f"  S5: launch / step(dN = 100) = {launch_us / comparison[100]['single_us']:.2f} (paper: somewhat below 1)")
    print(f"  S5: step cost ~ {intercept:.0f} + {slope:.0f} * dN us, R^2 = {r2:.3f} (paper: about linear)")
    print(f"  S5: ratio / step(dN = 1) = {ratio_us / comparison[1]['single_us']:.2f} (paper: several times less)")
    print(f"  total bench time {time.perf_counter() - started:.1f} s")
    print(
        json.dumps(
            {
                "bench": "lbl_nav",
                "epoch_update_dN10_us": round(epoch_us, 1),
                "launch_L12_gn5_us": round(launch_us, 1),
                "core_step_catching_up_us": round(core_us, 1),
                "ratio_decision_us": round(ratio_us, 1),
                "kf_kf_over_kf_pct": {str(k): round(v["ratio_pct"], 1) for k, v in comparison.items()},
                "single_step_us": {str(k): round(v["single_us"], 1) for k, v in comparison.items()},
                "launch_over_step_dN100": round(launch_us / comparison[100]["single_us"], 3),
                "step_cost_linear_fit_us": {
                    "intercept": round(float(intercept), 1),
                    "per_dN": round(float(slope), 1),
                    "r2": round(r2, 4),
                },
                "ratio_over_step_dN1": round(ratio_us / comparison[1]["single_us"], 3),
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
