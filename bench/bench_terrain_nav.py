"""Terrain navigation (digest 001): AT-13 speed-up, cell-rate update cost, window memory.

* **AT-13 speed-up**: the base algorithm (§2.13: per sample, bilinear reads, N_p = N_s = 1, argmin every
  sample, fix at N_min) against the modified one (cell rate, N_p = 4, N_s = 8) on the *same* simulated
  flights, both fed the paper's synchronised input tuple ``(t, x_ins, z_ins, h_ins, h_ra, i_ra)`` through
  ``push_sample`` (block 1 onwards); CPU time per flight, mean ratio base/modified, at f_s/f_cell = 12.5
  (20 Hz) and 5 (8 Hz). The same ratio through the full message path (``step()``, pydantic inputs and
  outputs, synchronisation) is printed too.
* **One cell-rate update**: KF bank + window push of one measurement (inside a group of N_p = 4), and one
  evaluation (argmin + C1-C4), over a 51 x 51 and a 201 x 201 hypothesis grid, microseconds.
* **Window memory**: bytes of the per-hypothesis window arrays (segment sums + open segment + F) at their
  largest during a flight, against the base algorithm's per-sample window.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time

import numpy as np

from services.terrain_nav.base_algorithm import BaseRecurrentSearch
from services.terrain_nav.config import TerrainNavConfig
from services.terrain_nav.core import TerrainNavigator
from services.terrain_nav.maps import ReferenceMap
from services.terrain_nav.resampler import CellMeasurement
from services.terrain_nav.simulation import FlightScenario, SimulatedFlight, simulate
from services.terrain_nav.terrain import make_terrain
from shared.service import InputRejected

from .report import emit


def _samples(fl: SimulatedFlight) -> list[tuple[float, float, float, float, float, bool, float, float]]:
    return [
        (
            float(fl.t[k]),
            float(fl.x_ins[k]),
            float(fl.z_ins[k]),
            float(fl.h_ins[k]),
            float(fl.h_ra[k]),
            bool(fl.ra_valid[k]),
            float(fl.vx_ins[k]),
            float(fl.vh_ins[k]),
        )
        for k in range(fl.tau.size)
    ]


def _cpu(nav: TerrainNavigator, samples: list[tuple[float, float, float, float, float, bool, float, float]]) -> float:
    push = nav.push_sample
    t0 = time.process_time()
    for s in samples:
        push(*s)
    return time.process_time() - t0


def _cpu_messages(nav: TerrainNavigator, fl: SimulatedFlight) -> float:
    msgs = list(fl.messages())
    t0 = time.process_time()
    for m in msgs:
        with contextlib.suppress(InputRejected):
            nav.step(m)
    return time.process_time() - t0


def speedup(rate_hz: float, runs: int) -> dict[str, float]:
    sc = FlightScenario(rate_hz=rate_hz)
    cfg = TerrainNavConfig(preset="paper", base_sample_rate_hz=rate_hz)
    ratios, ratios_msg, t_base, t_mod = [], [], [], []
    for seed in range(runs):
        fl = simulate(sc, 500 + seed)
        ref = fl.world.ref_map
        samples = _samples(fl)
        _cpu(TerrainNavigator(ref, cfg), samples[:50])  # warm-up
        tb = _cpu(BaseRecurrentSearch(ref, cfg), samples)
        tm = _cpu(TerrainNavigator(ref, cfg), samples)
        ratios.append(tb / tm)
        t_base.append(tb)
        t_mod.append(tm)
        if seed < max(2, runs // 4):
            ratios_msg.append(
                _cpu_messages(BaseRecurrentSearch(ref, cfg), fl) / _cpu_messages(TerrainNavigator(ref, cfg), fl)
            )
    return {
        "f_s_over_f_cell": rate_hz * 125.0 / 200.0,
        "ratio_mean": float(np.mean(ratios)),
        "ratio_min": float(np.min(ratios)),
        "base_ms_per_flight": 1e3 * float(np.mean(t_base)),
        "modified_ms_per_flight": 1e3 * float(np.mean(t_mod)),
        "ratio_message_path": float(np.mean(ratios_msg)),
        "runs": runs,
    }


def preset_cost(runs: int) -> dict[str, float]:
    """CPU ms per 20 Hz flight (push_sample) of the paper and robust presets, interleaved on the same flights,
    and per fix: robust's extra cost over paper divided by its fixes (the refinement's replay)."""
    t = {"paper": 0.0, "robust": 0.0}
    fixes = 0
    for seed in range(runs):
        fl = simulate(FlightScenario(), 500 + seed)
        ref = fl.world.ref_map
        samples = _samples(fl)
        for preset in t:
            nav = TerrainNavigator(ref, TerrainNavConfig(preset=preset))
            t[preset] += _cpu(nav, samples)
            if preset == "robust":
                fixes += nav.counters["fixes"]
    return {
        "paper_ms_per_flight": 1e3 * t["paper"] / runs,
        "robust_ms_per_flight": 1e3 * t["robust"] / runs,
        "robust_extra_ms_per_fix": 1e3 * (t["robust"] - t["paper"]) / max(fixes, 1),
        "fixes_per_flight": fixes / runs,
        "runs": runs,
    }


def update_cost(M: int, n_meas: int = 400, preset: str = "paper") -> dict[str, float]:
    """CPU microseconds per cell-rate update and per evaluation (with fix formation) over a (2M+1)^2 grid."""
    rng = np.random.default_rng(1)
    n_i, n_j = 2 * M + 200, 2 * M + 40
    dem = make_terrain("informative", (n_i, n_j), rng)
    ref = ReferenceMap(dem=dem, cell_m=125.0)
    cfg = TerrainNavConfig(preset=preset, M_x=M, M_z=M, N_p=4)
    nav = TerrainNavigator(ref, cfg)
    J = n_j // 2
    meas = [
        CellMeasurement(
            t=0.625 * k,
            I=M + 10 + k % 150,
            J=J,
            x_mean=(M + 10.5 + k % 150) * 125.0,
            z_mean=(J + 0.5) * 125.0,
            h_ins=2000.0,
            h_ra=float(2000.0 - dem[M + 10 + k % 150, J]),
            n=12,
            v_ground=200.0,
            vh_ins=0.0,
            t_first=0.0,
            t_last=0.0,
        )
        for k in range(n_meas)
    ]
    groups = [meas[k : k + 4] for k in range(0, n_meas, 4)]
    t_upd = t_eval = 0.0
    for g in groups:
        g = [dataclasses.replace(m) for m in g]
        t0 = time.process_time()
        nav.search.process_group(g)
        t1 = time.process_time()
        nav.search.evaluate()
        t2 = time.process_time()
        t_upd += t1 - t0
        t_eval += t2 - t1
    return {
        "grid": float(2 * M + 1),
        "update_us": 1e6 * t_upd / n_meas,
        "evaluation_us": 1e6 * t_eval / len(groups),
        "per_measurement_us": 1e6 * (t_upd + t_eval) / n_meas,
    }


def window_memory() -> dict[str, float]:
    fl = simulate(FlightScenario(), 42)
    cfg = TerrainNavConfig(preset="paper")
    nav = TerrainNavigator(fl.world.ref_map, cfg)
    base = BaseRecurrentSearch(fl.world.ref_map, cfg)
    most = most_base = 0
    arrays = 0
    for s in _samples(fl):
        nav.push_sample(*s)
        base.push_sample(*s)
        most = max(most, nav.window.memory_bytes())
        arrays = max(arrays, nav.window.stored_arrays())
        most_base = max(most_base, base.window.memory_bytes())
    return {
        "modified_bytes": float(most),
        "modified_arrays": float(arrays),
        "kf_state_bytes": float(nav.bank.x.nbytes),
        "base_bytes": float(most_base),
        "reduction": most_base / most,
    }


def main() -> None:
    s20 = speedup(20.0, 30)
    s8 = speedup(8.0, 30)
    u51 = update_cost(25, n_meas=800)
    u51r = update_cost(25, n_meas=800, preset="robust")
    pc = preset_cost(10)
    u201 = update_cost(100, n_meas=200)
    mem = window_memory()
    rows = [
        (
            "AT-13 speed-up base/modified, f_s/f_cell = 12.5 (20 Hz)",
            f"{s20['ratio_mean']:.1f}x",
            f"min {s20['ratio_min']:.1f}x; {s20['base_ms_per_flight']:.0f} vs "
            f"{s20['modified_ms_per_flight']:.1f} ms/flight",
        ),
        (
            "AT-13 speed-up base/modified, f_s/f_cell = 5 (8 Hz)",
            f"{s8['ratio_mean']:.1f}x",
            f"min {s8['ratio_min']:.1f}x; {s8['base_ms_per_flight']:.0f} vs "
            f"{s8['modified_ms_per_flight']:.1f} ms/flight",
        ),
        (
            "same, whole message path (step), 20 Hz / 8 Hz",
            f"{s20['ratio_message_path']:.1f}x / {s8['ratio_message_path']:.1f}x",
            "incl. pydantic messages and synchronisation",
        ),
        (
            "cell-rate update, 51 x 51 grid",
            f"{u51['update_us']:.0f} µs",
            f"evaluation + fix {u51['evaluation_us']:.0f} µs per group",
        ),
        (
            "same, robust preset (refinement at every fix)",
            f"{u51r['update_us']:.0f} µs",
            f"evaluation + fix {u51r['evaluation_us']:.0f} µs per group",
        ),
        (
            "20 Hz flight, paper / robust preset (push_sample)",
            f"{pc['paper_ms_per_flight']:.1f} / {pc['robust_ms_per_flight']:.1f} ms",
            f"robust's extra {pc['robust_extra_ms_per_fix']:.2f} ms per fix, {pc['fixes_per_flight']:.1f} fixes/flight",
        ),
        (
            "cell-rate update, 201 x 201 grid",
            f"{u201['update_us']:.0f} µs",
            f"evaluation + fix {u201['evaluation_us']:.0f} µs per group",
        ),
        (
            "window memory, 51 x 51, N_max 64, N_s 8",
            f"{mem['modified_bytes'] / 1e3:.0f} kB",
            f"{mem['modified_arrays']:.0f} arrays + F; base {mem['base_bytes'] / 1e6:.1f} MB ({mem['reduction']:.0f}x)",
        ),
    ]
    emit(
        "terrain_nav",
        ["figure", "value", "detail"],
        rows,
        {
            "speedup_20hz": s20,
            "speedup_8hz": s8,
            "update_51": u51,
            "update_51_robust": u51r,
            "presets_20hz": pc,
            "update_201": u201,
            "window_memory": mem,
        },
    )


if __name__ == "__main__":
    main()
