"""Issue 16: the reliability conditions over families of terrain, a new terrain every run (small N).

The large-N run is ``python -m bench.bench_terrain_families`` (docs/terrain_nav.md, "Terrain families"); this is
its small version for the default test run. The digest's bound (001 §4, AT-3): at most 0.5 % of the fixes more
than 1 cell off and none more than 1.5 cells. A few hundred fixes cannot show 0.5 %, so the test asserts what
they can: no fix > 1.5 cells, and no more fixes > 1 cell than a rate of 0.5 % gives with 95 % probability
(the binomial 95 % quantile; the count is one-sided evidence against the bound). AT-15 (the vertical channel,
>= 95 % of the fixes within 3 sqrt(P_hh)) is checked on smooth terrain, where the paper's P_hh misses the slope
term (services/terrain_nav/models.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import binom

from services.terrain_nav.config import TerrainNavConfig
from services.terrain_nav.maps import ReferenceMap
from services.terrain_nav.metrics import fix_errors_cells
from services.terrain_nav.models import mean_slope
from services.terrain_nav.offline import run_flight
from services.terrain_nav.resampler import CellMeasurement
from services.terrain_nav.simulation import FlightScenario, SimulatedFlight, make_world, simulate_flight
from services.terrain_nav.worlds import coarse_partly_flat_world

DIGEST_FALSE_RATE = 0.005  # AT-3: <= 0.5 % of the fixes > 1 cell
DIGEST_MAX_CELLS = 1.5  # AT-3: none > 1.5 cells
COARSE = FlightScenario(cell_m=2400.0, start_cell=(30, 55), rate_hz=2.0, sigma_da_mps2=1e-5)


@dataclass
class Tally:
    fixes: int = 0
    false: int = 0
    worst: float = 0.0
    vert_in: int = 0
    runs_with_fix: int = 0


def _flight(family: str, run: int) -> SimulatedFlight:
    """A new world and flight per run (the bench's seeding with another root seed)."""
    w_seq, f_seq = np.random.SeedSequence([1616, run]).spawn(2)
    if family == "coarse partly flat":
        return simulate_flight(COARSE, coarse_partly_flat_world(run, np.random.default_rng(w_seq)),
                               np.random.default_rng(f_seq))  # fmt: skip
    sc = {
        "H 0.35": FlightScenario(H=0.35, duration_s=66.0),
        "H 0.85": FlightScenario(H=0.85, duration_s=66.0),
        "corr 10 cells": FlightScenario(corr_cells=10.0, duration_s=66.0),
        "low relief 3 m": FlightScenario(rms_inc_m=3.0),
    }[family]
    return simulate_flight(sc, make_world(sc, np.random.default_rng(w_seq)), np.random.default_rng(f_seq))


def _tally(family: str, runs: int, cfg: TerrainNavConfig) -> Tally:
    t = Tally()
    for r in range(runs):
        fl = _flight(family, r)
        fixes = run_flight(fl, cfg).fixes
        t.runs_with_fix += bool(fixes)
        for f in fixes:
            ex, ez = fix_errors_cells(f, fl)
            e = max(abs(ex), abs(ez))
            t.fixes += 1
            t.false += e > 1.0
            t.worst = max(t.worst, e)
            dh_true = fl.truth_at(f.header.stamp_ns * 1e-9)["dh"]
            dh = f.vertical.index("dh")
            t.vert_in += abs(f.vertical.mean[dh] - dh_true) <= 3.0 * math.sqrt(f.vertical.covariance[dh][dh])
    return t


@pytest.mark.parametrize(
    ("family", "runs", "min_fixes"),
    [("H 0.35", 10, 100), ("H 0.85", 10, 100), ("corr 10 cells", 10, 60), ("coarse partly flat", 8, 150),
     ("low relief 3 m", 10, 0)],
)  # fmt: skip
def test_the_default_preset_keeps_the_digest_false_fix_bound_over_terrain_families(
    family: str, runs: int, min_fixes: int
) -> None:
    """Default (robust) preset, a new terrain every run: none > 1.5 cells, the > 1 cell count within the
    binomial 95 % quantile of 0.5 %. ``min_fixes`` (about half of what the bench measures per run, see
    docs/terrain_nav.md) keeps the test from passing by fixing nothing; low relief may legitimately not fix."""
    t = _tally(family, runs, TerrainNavConfig())
    assert t.fixes >= min_fixes
    assert t.worst <= DIGEST_MAX_CELLS, f"{family}: a fix {t.worst:.2f} cells off"
    assert t.false <= binom.ppf(0.95, t.fixes, DIGEST_FALSE_RATE), f"{family}: {t.false} of {t.fixes} > 1 cell"


def test_the_slope_term_restores_at15_on_smooth_terrain() -> None:
    """H = 0.85: the dh of a hypothesis is that of the cell centres, off by slope x horizontal error, and on
    smooth terrain the slope keeps its sign along the track. AT-15 asks >= 95 % of the fixes within 3 sqrt(P_hh);
    with the slope term (robust) it holds on these flights, without it (paper) the share is lower (measured:
    87 % against 97 % on 15 flights, docs/terrain_nav.md)."""
    robust = _tally("H 0.85", 12, TerrainNavConfig(preset="robust"))
    paper = _tally("H 0.85", 12, TerrainNavConfig(preset="paper"))
    assert robust.fixes == paper.fixes > 100  # the slope term changes no horizontal decision
    assert robust.vert_in / robust.fixes >= 0.95
    assert paper.vert_in < robust.vert_in


@settings(max_examples=25, deadline=None)
@given(a=st.floats(-0.2, 0.2), b=st.floats(-0.2, 0.2), i=st.integers(-5, 5), j=st.integers(-5, 5))
def test_mean_slope_of_a_plane_is_its_gradient(a: float, b: float, i: int, j: int) -> None:
    """On the plane H = a x + b z (m) the mean slope read by any hypothesis is (a, b), also at the map's edge rows
    (one-sided differences are exact on a plane)."""
    cell = 125.0
    x = (np.arange(30)[:, None] + 0.5) * cell
    z = (np.arange(20)[None, :] + 0.5) * cell
    ref = ReferenceMap(dem=a * x + b * z + 800.0, cell_m=cell)
    window = [CellMeasurement(t=float(k), I=5 + k, J=8, x_mean=0.0, z_mean=0.0, h_ins=0.0, h_ra=0.0, n=10,
                              v_ground=200.0, vh_ins=0.0, t_first=0.0, t_last=0.0) for k in range(18)]  # fmt: skip
    g = mean_slope(window, ref, i, j)
    assert g == pytest.approx([a, b], abs=1e-9)
