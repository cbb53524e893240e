"""RD-LBL navigation (digest 002): particle-filter update per cycle for 300 / 1,000 / 10,000 particles, the
EKF shadow update, the coordinator's beacon-set selection for 10 and 50 candidates, and the in-process
closed loop's speed. Prints a table and one JSON line (``JSON {...}``); all ratios from this one run.
"""

from __future__ import annotations

import json
import math
import platform
import time
from collections.abc import Callable

import numpy as np

from bench.report import table
from services.coordinator.config import CoordinatorConfig
from services.coordinator.selection import select
from services.rd_nav.config import RdNavConfig
from services.rd_nav.ekf import EkfShadow
from services.rd_nav.geometry import leader_follower_ranges, measurement_cov, noise_free_tdoa
from services.rd_nav.offline import run
from services.rd_nav.pf import ParticleFilter
from services.rd_nav.simulation import ref

APEX = math.sqrt(2900.0**2 - 1500.0**2)
LEADER = np.array([APEX, 1500.0, 100.0])
FOLLOWERS = np.array([[0.0, 0.0, 100.0], [0.0, 3000.0, 100.0]])
P1 = np.array([827.0, 1500.0])
Z = 80.0


def per_call_s(fn: Callable[[], object], budget_s: float = 1.0, min_calls: int = 20) -> float:
    """Median of batches of calls until the budget is spent (seconds per call)."""
    samples = []
    t_end = time.perf_counter() + budget_s
    while time.perf_counter() < t_end or len(samples) < min_calls:
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return float(np.median(samples))


def cycle_data() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    _, d, s, _, _ = noise_free_tdoa(np.array([*P1, Z]), LEADER, FOLLOWERS, np.array([0.5, 3.5]), 1500.0)
    R = measurement_cov(s, 1500.0, 0.2e-3, 0.0, 0.3)
    delta = np.array([[1.2, 3.1], [3.9, 7.6]])
    return d, R, delta, np.full(2, Z)


def pf_cycle_time(n: int) -> float:
    """One PF cycle: predict (Eq. 5 + diffusion), weight (robust Gaussian), normalise, estimate (Eq. 6-7),
    N_eff, systematic resampling + roughening (done every cycle here: the worst case)."""
    rng = np.random.default_rng(1)
    pf = ParticleFilter(n, rng)
    pf.init_disc(P1, 10.0)
    d, R, delta, zj = cycle_data()
    Rinv = np.linalg.inv(R)
    dX = np.array([10.0, 11.0])

    def one() -> None:
        pf.predict(dX, 1.35)
        pf.X -= dX  # stay near the data so the weights remain informative
        pf.weight(d, Rinv, LEADER, FOLLOWERS, delta, Z, zj, 0.05, 25.0)
        pf.estimate()
        pf.n_eff()
        pf.resample(0.1)

    return per_call_s(one)


def ekf_update_time() -> float:
    ekf = EkfShadow()
    ekf.init(P1, np.eye(2))
    d, R, delta, zj = cycle_data()

    def one() -> None:
        ekf.predict(np.zeros(2), 1.8)
        ekf.update(d, R, LEADER, FOLLOWERS, delta, Z, zj, 13.8)
        ekf.init(P1, np.eye(2))

    return per_call_s(one)


def selection_time(n_beacons: int) -> float:
    rng = np.random.default_rng(n_beacons)
    beacons = {f"b{k:02d}": np.array([*rng.uniform(-5000, 5000, 2), 100.0]) for k in range(n_beacons)}
    route = np.column_stack([np.linspace(-2000, 2000, 20), np.linspace(-1000, 1500, 20), np.full(20, 80.0)])
    cfg = CoordinatorConfig()
    return per_call_s(lambda: select(beacons, route, None, cfg, 2), budget_s=2.0, min_calls=5)


def closed_loop_cpu_per_hour() -> float:
    t0 = time.process_time()
    run(
        ref("inside", duration_s=1800.0), 1, RdNavConfig(propagated_fix_period_s=0.0, emit_propagated_after_cycle=False)
    )
    return (time.process_time() - t0) / 0.5


def main() -> None:
    _ = leader_follower_ranges(LEADER, FOLLOWERS)  # warm numpy up
    pf = {n: pf_cycle_time(n) for n in (300, 1000, 10_000)}
    ekf = ekf_update_time()
    sel = {n: selection_time(n) for n in (10, 50)}
    loop = closed_loop_cpu_per_hour()
    rows = [
        ("PF cycle update, N = 300", f"{pf[300] * 1e3:.3f} ms"),
        ("PF cycle update, N = 1,000 (target < 1 ms)", f"{pf[1000] * 1e3:.3f} ms"),
        ("PF cycle update, N = 10,000", f"{pf[10_000] * 1e3:.3f} ms"),
        ("EKF shadow predict + update", f"{ekf * 1e6:.1f} us"),
        ("beacon-set selection, 10 candidates (120 triads)", f"{sel[10] * 1e3:.2f} ms"),
        ("beacon-set selection, 50 candidates (19,600 triads)", f"{sel[50] * 1e3:.1f} ms"),
        ("closed loop sim + core (REF inside), CPU per simulated hour", f"{loop:.2f} s"),
        ("ratio PF N=10,000 / N=1,000", f"{pf[10_000] / pf[1000]:.1f}"),
        ("ratio selection 50 / 10", f"{sel[50] / sel[10]:.0f}"),
    ]
    print("\n## rd_nav\n")
    print(table(["figure", "value"], rows))
    doc = {
        "benchmark": "rd_nav",
        "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()},
        "pf_cycle_ms": {str(n): round(v * 1e3, 4) for n, v in pf.items()},
        "ekf_update_us": round(ekf * 1e6, 2),
        "selection_ms": {str(n): round(v * 1e3, 3) for n, v in sel.items()},
        "closed_loop_cpu_s_per_sim_hour": round(loop, 3),
    }
    print("JSON " + json.dumps(doc, sort_keys=True))


if __name__ == "__main__":
    main()
