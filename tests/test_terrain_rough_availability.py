"""Issue 16, rough terrain: C3 withheld fixes the exact posterior already called, because of distant minima.

On rough terrain (Hurst 0.35, short correlation length, low relief) the window's best wrong offset, 10-40 cells
from the argmin, reaches F ~ 1.7-2.8 F_min: inside the paper's region F <= (1 + mu3) F_min, so C3 fails,
while the likelihood gap (F - F_min)/(2 s) ~ N/2 already excludes it (docs/terrain_nav.md, "Rough terrain:
availability"). The option ``c3_evidence`` drops such distant cells from the region; nearer cells keep the
paper's test, which is what guards the one-cell slips of low relief. It is not in the robust preset: on the
coarse partly flat map it let through false fixes 8-22 cells off (4 of 11 594 fixes in 251 runs).
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from services.terrain_nav.conditions import d_max, evidence_gap
from services.terrain_nav.config import TerrainNavConfig
from services.terrain_nav.metrics import fix_errors_cells
from services.terrain_nav.offline import run_flight
from services.terrain_nav.simulation import FlightScenario, make_world, simulate_flight

#: the sweep's point that reproduces the issue's figure (paper and robust 80.0 % within 40 s over 30 runs)
ROUGH = FlightScenario(H=0.35, corr_cells=10.0)


def _distant_minimum() -> np.ndarray:
    F = np.full((51, 51), 100.0)
    F[25, 25] = 10.0  # the argmin
    F[24:27, 24:27] = np.maximum(F[24:27, 24:27], 30.0)
    F[25, 25] = 10.0
    F[45, 25] = 20.0  # a distant minimum 20 cells away at 2 F_min: inside (1 + 1.5) F_min = 25
    return F


def test_a_distant_minimum_fails_the_paper_c3_and_drops_out_beyond_the_evidence_gap() -> None:
    F = _distant_minimum()
    assert d_max(F, 25, 25, 1.5) == 20.0  # the paper's region reaches the distant minimum: C3 fails
    assert d_max(F, 25, 25, 1.5, gap_cap=9.9, cap_beyond=4.0) == 0.0  # gap 10 > 9.9: out
    assert d_max(F, 25, 25, 1.5, gap_cap=10.0, cap_beyond=4.0) == 20.0  # gap 10 <= 10: still in
    assert d_max(F, 25, 25, 1.5, gap_cap=0.0, cap_beyond=20.0) == 20.0  # within cap_beyond: the paper's test


def test_the_evidence_gap_uses_the_median_expected_residual_or_the_fit_whichever_is_larger() -> None:
    # S_k of the start (unknown dh, 1e4 m^2) does not set the noise level; 2 * 15 * median(40, 50, 60, 1e4) = 1650
    assert evidence_gap(15.0, [1e4, 40.0, 50.0, 60.0, 0.0], 100.0, 4) == 2 * 15.0 * 55.0
    # a fit worse than the model expects (F_min/N = 100 m^2 > 55) widens the gap: 2 * 15 * 100
    assert evidence_gap(15.0, [1e4, 40.0, 50.0, 60.0], 400.0, 4) == 3000.0


@settings(max_examples=60, deadline=None)
@given(
    arrays(np.float64, (9, 11), elements=st.floats(0.0, 1e3)),
    st.floats(0.0, 1e3),
    st.floats(0.0, 15.0),
)
def test_the_evidence_cap_only_shrinks_the_region_and_never_near_the_argmin(
    F: np.ndarray, cap: float, beyond: float
) -> None:
    a, b = divmod(int(np.argmin(F)), F.shape[1])
    full = d_max(F, a, b, 1.5)
    capped = d_max(F, a, b, 1.5, gap_cap=cap, cap_beyond=beyond)
    assert capped <= full
    ii, jj = np.nonzero(2.5 * F[a, b] >= F)
    dist = np.hypot(ii - a, jj - b)
    assert capped >= dist[dist <= beyond].max()  # qualifying cells within ``beyond`` are never dropped
    assert d_max(F, a, b, 1.5, gap_cap=cap, cap_beyond=15.0) == full  # the whole 9 x 11 grid lies within 15 cells


def _available(cfg: TerrainNavConfig, runs: int) -> tuple[int, int, float]:
    """Runs with a fix within 40 s, fixes, worst fix error (cells) over ``runs`` flights, a new terrain each."""
    available, fixes, worst = 0, 0, 0.0
    for r in range(runs):
        w_seq, f_seq = np.random.SeedSequence([1616, r]).spawn(2)
        flight = simulate_flight(ROUGH, make_world(ROUGH, np.random.default_rng(w_seq)), np.random.default_rng(f_seq))
        out = run_flight(flight, cfg).fixes
        fixes += len(out)
        worst = max([worst, *(max(map(abs, fix_errors_cells(f, flight))) for f in out)])
        available += bool(out) and out[0].header.stamp_ns * 1e-9 - flight.t0_s <= 40.0
    return available, fixes, worst


def test_c3_evidence_fixes_rough_terrain_in_time_and_only_correctly() -> None:
    """24 flights of the issue's reproduction (H 0.35, correlation 10 cells), a new terrain each. Both presets
    fixed 80.0 % of the sweep's 30 runs within 40 s before ``c3_evidence`` (docs/terrain_nav.md); the paper
    preset still misses some here (the issue's failure), robust with ``c3_evidence=15`` at most 2 (at a true 80 %,
    >= 22 of 24 has probability 11 %; measured 100 % over the sweep's 30 runs). No fix may be > 1 cell off."""
    assert TerrainNavConfig().c3_evidence is None  # an option, not the default (see above)
    robust, fixes, worst = _available(TerrainNavConfig(c3_evidence=15.0), 24)
    paper, _, _ = _available(TerrainNavConfig(preset="paper"), 24)
    assert worst <= 1.0
    assert fixes >= 24 * 8  # about half the fixes per run the bench measures (16.5)
    assert paper <= 21
    assert robust >= 22 and robust > paper
