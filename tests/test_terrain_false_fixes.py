"""Issue 16: false fixes on coarse, partly flat maps; any heading; the exact posterior as a reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.terrain_nav.config import TerrainNavConfig
from services.terrain_nav.maps import ReferenceMap
from services.terrain_nav.offline import run_flight
from services.terrain_nav.posterior import exact_posterior
from services.terrain_nav.resampler import CellMeasurement
from services.terrain_nav.simulation import FlightScenario, make_world, simulate_flight
from services.terrain_nav.terrain import fbm_2d
from services.terrain_nav.worlds import coarse_partly_flat_world


def _errors(flight, res) -> list[float]:  # type: ignore[no-untyped-def]
    out = []
    for fx in res.fixes:
        d = flight.truth_at(fx.header.stamp_ns * 1e-9)
        out.append(max(abs(fx.dx_m - d["dx"]), abs(fx.dz_m - d["dz"])) / flight.cell_m)
    return out


def test_the_c3_floor_blocks_the_false_fix_of_a_coarse_partly_flat_map() -> None:
    """2.4 km cells, mountains beyond the middle of z, a plain before it, the aircraft near the edge.

    The paper's C3 (F <= 2.5 F_min) issues a fix 24 cells off here: the true hypothesis carries the large
    cell-quantisation mismatch of steep terrain (F_true/N ~ 12 000 m^2) while a hypothesis on the plain
    fits the detrended profile better than the model's own noise (F_min/N = 505 m^2 against R_k ~ 2 600 m^2),
    so the region "within 2.5 F_min" shrinks to a point and C1-C4 all hold. With the floor (region at least
    F_min + mu3 * 0.5 * sum S_k) the plain's hypotheses stay in the region and C3 blocks.
    """
    world = coarse_partly_flat_world(25, np.random.default_rng(1025))
    sc = FlightScenario(cell_m=2400.0, start_cell=(30, 55), rate_hz=2.0, sigma_da_mps2=1e-5)
    flight = simulate_flight(sc, world, np.random.default_rng(25))
    paper = _errors(flight, run_flight(flight, TerrainNavConfig(preset="paper")))
    robust = _errors(flight, run_flight(flight, TerrainNavConfig(preset="robust")))
    assert max(paper) > 10.0  # the failure the issue reports (here 24 cells)
    assert robust and max(robust) <= 1.0  # the robust preset still fixes this flight, and only correctly


def test_the_paper_preset_is_the_digest_configuration_and_robust_the_default() -> None:
    assert TerrainNavConfig(preset="paper").c3_floor is None and TerrainNavConfig(preset="robust") == TerrainNavConfig()
    robust = TerrainNavConfig(preset="robust")
    assert robust.c3_floor == 0.5 and TerrainNavConfig(preset="robust", c3_floor=0.25).c3_floor == 0.25
    assert robust.vertical_slope_term and not TerrainNavConfig(preset="paper").vertical_slope_term
    assert robust.refine and robust.refine_sigma_floor_cells == 0.3 and not TerrainNavConfig(preset="paper").refine
    assert robust.refine_vertical and not TerrainNavConfig(preset="paper").refine_vertical
    robust_only = {"preset", "c3_floor", "vertical_slope_term", "refine", "refine_sigma_floor_cells", "refine_vertical"}
    assert robust.model_dump(exclude=robust_only) == TerrainNavConfig(preset="paper").model_dump(exclude=robust_only)


@pytest.mark.parametrize("heading_deg", [30.0, 135.0, 250.0])
def test_straight_flights_at_any_heading_fix_within_a_cell(heading_deg: float) -> None:
    """The hypothesis grid lives in map axes and the gap timing uses the INS's 2-D ground speed, so a flight
    at any heading over the digest's informative terrain gives AT-3's result: a fix, none > 1 cell (the
    digest's bound: <= 0.5 % of fixes > 1 cell, none > 1.5; 3 flights of ~20 fixes cannot show more)."""
    c, s = math.cos(math.radians(heading_deg)), math.sin(math.radians(heading_deg))
    errs: list[float] = []
    for seed in range(3):
        ss = np.random.SeedSequence([16, seed]).spawn(2)
        sc = FlightScenario(
            map_cells=(200, 200), start_cell=(int(100 - 35 * c), int(100 - 35 * s)), heading_deg=heading_deg
        )
        flight = simulate_flight(sc, make_world(sc, np.random.default_rng(ss[0])), np.random.default_rng(ss[1]))
        e = _errors(flight, run_flight(flight, TerrainNavConfig(preset="robust")))
        assert e, f"no fix at heading {heading_deg}"
        errs += e
    assert max(errs) <= 1.0


@settings(max_examples=20, deadline=None)
@given(i=st.integers(-6, 6), j=st.integers(-6, 6), dh=st.floats(-80.0, 80.0), seed=st.integers(0, 10_000))
def test_exact_posterior_puts_its_mass_on_the_true_offset(i: int, j: int, dh: float, seed: int) -> None:
    """Property: noise-free measurements of rough terrain taken at offset (i, j) with any altitude bias give
    a posterior mode at (i, j) holding almost all the mass (the bias is a nuisance parameter of the model)."""
    rng = np.random.default_rng(seed)
    ref = ReferenceMap(dem=fbm_2d((60, 40), rng, 0.6, 12.0) + 500.0, cell_m=125.0)
    cfg = TerrainNavConfig(M_x=8, M_z=8)
    window = []
    for k in range(30):
        I, J = 15 + k, 20  # noqa: E741 - cell index
        terrain = ref.dem[I + i, J + j]
        window.append(CellMeasurement(t=0.625 * k, I=I, J=J, x_mean=0.0, z_mean=0.0, h_ins=1500.0 - dh,
                                      h_ra=1500.0 - terrain, n=12, v_ground=200.0, vh_ins=0.0,
                                      t_first=0.0, t_last=0.0))  # fmt: skip
    post = exact_posterior(window, ref, cfg)
    assert post.argmax == (i, j)
    assert post.p.sum() == pytest.approx(1.0)
    assert post.mass_within(i, j, 0.0) > 0.99
