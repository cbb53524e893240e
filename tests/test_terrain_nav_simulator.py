"""The terrain_nav player plugin, its scenario files and map files, and the ``fixstream mc`` plugin."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from conftest import fixstream_cmd
from test_terrain_nav_service import REPO, terrain_scenario, variant

from schemas import InsSample, RadioAltimeter, Truth
from services.player.scenario import ScenarioError, load_scenario, parse_scenario, scenario_files
from services.player.sensor_stats import sensor_stats
from services.player.timeline import SimulationError, build, scenario_events
from services.terrain_nav import mc
from services.terrain_nav.mapfiles import write_maps
from services.terrain_nav.maps import ReferenceMap, load_npy
from services.terrain_nav.simulation import simulate
from services.terrain_nav.simulator import TerrainFlightParams, check_same_map, generated_world
from shared import keys
from shared.foxglove.frames import FrameContext, estimates_of
from tools import montecarlo

SHIPPED = sorted(p for p in scenario_files(REPO / "scenarios") if p.name.startswith("terrain_nav_"))
INS_KEY, RA_KEY = "fixstream/sensor/tan1/ins/ins0", "fixstream/sensor/tan1/radalt/ra0"


def _params(name: str) -> TerrainFlightParams:
    p = terrain_scenario(name).simulator_params(0)
    assert isinstance(p, TerrainFlightParams)
    return p


# --- scenario and map files ----------------------------------------------------------------------------------------


def test_the_shipped_scenarios_cover_the_issue_and_name_their_estimator() -> None:
    names = {p.stem.removeprefix("terrain_nav_") for p in SHIPPED}
    assert {"paper_replica", "informative", "flat", "ridge_x", "ridge_z", "periodic", "demo"} <= names
    for path in SHIPPED:
        sc = load_scenario(path)
        assert "terrain_nav/tan1" in sc.wait_for or not sc.wait_for, path
        assert [(e.kind, e.instance) for e in sc.estimators] == [("terrain_nav", "tan1")], path
        params = sc.simulator_params(0)
        assert isinstance(params, TerrainFlightParams) and params.platform == "tan1"
        if params.terrain_file is not None:  # issue 16: a DEM file as the truth (the map: the same file)
            assert (REPO / params.terrain_file).stat().st_size < 1_000_000
            continue
        if params.terrain_seed is None:  # issue 16: terrain families, a new terrain every run (mc only)
            assert params.map_file is None and not sc.wait_for
            continue
        assert params.map_file is not None and params.terrain_seed is not None
        npy = REPO / params.map_file
        assert npy.stat().st_size < 2_000_000 and npy.with_suffix(".json").exists()
        build(sc, sc.seed)  # the simulator checks the map file against its terrain
    assert terrain_scenario("demo").duration_s <= 60.0


def _assert_same_map(a: ReferenceMap, b: ReferenceMap, where: str) -> None:
    """Same grid and voids, heights within MAP_TOLERANCE_M, map statistics within 1e-9 relative.

    A regenerated map is not bit-identical across machines and library builds (BLAS, libm and the FFT differ in
    the last bits: D1_m2 159.56307988251194 vs ...191 seen on a fresh install), so the check is the simulator's
    own tolerance: 1 µm of height is six orders of magnitude below the smallest error the model simulates (the
    altimeter's σ_v = 2 m, the map error σ_map) and cannot change a correlation decision."""
    check_same_map(a, b, where)
    for name in ("D1_m2", "sigma_t2_m2"):
        assert math.isclose(getattr(a, name), getattr(b, name), rel_tol=1e-9), (where, name)


def test_map_files_are_the_generated_maps_and_can_be_rewritten(tmp_path: Path) -> None:
    for name in ("informative", "periodic"):
        p = _params(name)
        assert p.terrain_seed is not None and p.map_file is not None
        shipped = load_npy(REPO / p.map_file)
        _assert_same_map(shipped, generated_world(p, p.terrain_seed).ref_map, p.map_file)
    doc = yaml.safe_load((REPO / "scenarios" / "terrain_nav_ridge_z.yaml").read_text())
    doc["simulators"][0]["params"]["map_file"] = str(tmp_path / "maps" / "rz.npy")
    path = tmp_path / "rz.yaml"
    path.write_text(yaml.safe_dump(doc))
    assert write_maps([path]) == [tmp_path / "maps" / "rz.npy"]
    shipped = _params("ridge_z").map_file
    assert shipped is not None
    _assert_same_map(load_npy(tmp_path / "maps" / "rz.npy"), load_npy(REPO / shipped), shipped)
    build(load_scenario(path), 0)


def test_a_map_file_of_another_terrain_is_refused() -> None:
    sc = variant("informative", terrain="ridge_x")  # still names the informative map
    with pytest.raises(SimulationError, match=r"map_file .* is not the map of this terrain.*mapfiles"):
        build(sc, 1)


def test_parameters_are_validated_with_field_names() -> None:
    cases: list[tuple[dict[str, Any], str]] = [
        ({"terrain_seed": None}, "map_file needs a fixed terrain_seed"),
        ({"start_cell": [250, 10]}, "start_cell"),
        ({"truth_rate_hz": 50.0}, "truth_rate_hz must not exceed rate_hz"),
        ({"sigma_v_m": -1.0}, "sigma_v_m"),
        ({"failures": [{"kind": "spike", "onset_s": 1.0, "duration_s": 1.0}]}, "failures"),
        ({"speed": 100.0}, "speed"),
        ({"terrain": "mountains"}, "terrain"),
    ]
    for change, match in cases:
        with pytest.raises(ScenarioError, match=match):
            variant("informative", **change)


# --- the simulated streams -----------------------------------------------------------------------------------------


def test_world_is_the_core_simulation_world() -> None:
    p = _params("informative")
    assert p.terrain_seed is not None
    ours = generated_world(p, p.terrain_seed)
    core = simulate(p.flight_scenario(), p.terrain_seed).world
    assert np.array_equal(ours.truth, core.truth) and np.array_equal(ours.ref_map.dem, core.ref_map.dem)


def test_streams_keys_stamps_and_enu_truth() -> None:
    sc = terrain_scenario("informative")
    sim = build(sc, 4)
    events = list(sim.raw_events())
    assert {e.key for e in events} == {INS_KEY, RA_KEY, keys.truth("tan1")}
    assert all(0 <= e.stamp_ns <= sc.duration_ns and e.msg.header.frame_id == sc.frame_id for e in events)
    ins = {e.stamp_ns: e.msg for e in events if isinstance(e.msg, InsSample)}
    truths = [e.msg for e in events if isinstance(e.msg, Truth)]
    assert len(ins) == sum(isinstance(e.msg, RadioAltimeter) for e in events) > 1200  # 20 Hz, ~65 s
    assert len(truths) == math.floor(len(ins) / 20) + (len(ins) % 20 > 0)  # 1 Hz
    exact = sim.context.platforms["tan1"].truth_at(np.array([t.header.stamp_ns for t in truths]))
    for k, t in enumerate(truths):
        east, north, up = t.position_m
        i = ins[t.header.stamp_ns]
        assert isinstance(i, InsSample)
        # true = indicated + correction, with x = north and z = east
        assert north == pytest.approx(i.x_m + t.extra["dx_m"], abs=1e-6)
        assert east == pytest.approx(i.z_m + t.extra["dz_m"], abs=1e-6)
        assert up == pytest.approx(i.h_m + t.extra["dh_m"], abs=1e-6)
        assert t.extra["terrain_seed"] == 1.0 and t.velocity_mps == [0.0, 200.0, 0.0]
        assert np.allclose(exact.position_m[k], t.position_m, atol=1e-6)
    # the built-in sensor statistics see the INS error the truth describes
    stats = sensor_stats(list(scenario_events(sc, 4)), sim.context.platforms)[INS_KEY]
    dx = [t.extra["dx_m"] for t in truths]
    assert stats["errors"]["x_m"]["mean"] == pytest.approx(-float(np.mean(dx)), abs=5.0)


def test_failures_are_injected_on_the_radio_altimeter() -> None:
    failures = [
        {"kind": "additive", "onset_s": 10.0, "duration_s": 3.0, "amplitude_m": 80.0},
        {"kind": "dropout", "onset_s": 20.0, "duration_s": 2.0},
        {"kind": "nan", "onset_s": 30.0, "duration_s": 0.5},
    ]
    clean = [e for e in build(terrain_scenario("informative"), 9).raw_events() if e.key == RA_KEY]
    bad = [e for e in build(variant("informative", failures=failures), 9).raw_events() if e.key == RA_KEY]
    assert [e.stamp_ns for e in clean] == [e.stamp_ns for e in bad]
    for c, b in zip(clean, bad, strict=True):
        assert isinstance(c.msg, RadioAltimeter) and isinstance(b.msg, RadioAltimeter)
        t = c.stamp_ns * 1e-9
        if 10.0 <= t < 13.0:
            assert b.msg.h_agl_m == pytest.approx(c.msg.h_agl_m + 80.0) and b.msg.valid  # false data, flag kept
        elif 20.0 <= t < 22.0:
            assert not b.msg.valid and b.msg.h_agl_m == c.msg.h_agl_m
        elif 30.0 <= t < 30.5:
            assert math.isnan(b.msg.h_agl_m)
        else:
            assert b.msg == c.msg


def test_drawn_terrain_differs_per_run_and_the_mc_plugin_rebuilds_it() -> None:
    sc = variant("informative", terrain_seed=None, map_file=None, flight_duration_s=30.0)
    seeds = []
    for run in (0, 1):
        events = list(build(sc, 7, run).raw_events())
        truth = next(e.msg for e in events if isinstance(e.msg, Truth))
        seeds.append(truth.extra["terrain_seed"])
    assert seeds[0] != seeds[1]
    metrics = montecarlo.run_once(sc, 7, 0)["estimators"]["tan1"]
    assert metrics["terrain_seed"] == seeds[0] and metrics["n_fixes"] >= 1 and metrics["n_false_fixes"] == 0


# --- fixstream mc -----------------------------------------------------------------------------------------------------

MC_KEYS = {
    "availability",
    "first_fix_s_median",
    "first_fix_s_p90",
    "fixes",
    "fixes_within_1_cell",
    "max_abs_error_cells",
    "false_fix_rate",
    "states",
    "c2_false_after_c1",
    "c3_false_after_c1",
    "c4_false_after_c1",
    "vertical_within_3sigma",
    "vertical_abs_error_median_m",
    "vertical_full_window_median_m",
    "vertical_full_window_p95_m",
    "rejected",
}


def test_fixstream_mc_writes_the_metrics_identically_for_one_and_two_workers(tmp_path: Path) -> None:
    path = REPO / "scenarios" / "terrain_nav_demo.yaml"
    outs = []
    for workers in ("1", "2"):
        out = tmp_path / f"w{workers}.json"
        proc = subprocess.run(
            fixstream_cmd("mc", str(path), "--runs", "2", "--seed", "3", "--out", str(out), "--workers", workers),
            capture_output=True,
            text=True,
            cwd=tmp_path,  # map files are found from the repository root too
            timeout=300,
        )
        assert proc.returncode == 0, proc.stderr
        outs.append(out.read_text())
    assert outs[0] == outs[1]
    doc = json.loads(outs[0])
    agg = doc["aggregate"]["estimators"]["tan1"]
    assert set(agg) >= MC_KEYS
    assert agg["runs"] == 2 and agg["availability"] == 1.0 and agg["false_fix_rate"] == 0.0
    assert agg["fixes"] == sum(r["estimators"]["tan1"]["n_fixes"] for r in doc["per_run"]) > 0
    # the demo's NaN samples and dropout are counted as refused inputs
    sc = load_scenario(path)
    ra = [e.msg for run in (0, 1) for e in build(sc, 3, run).raw_events() if isinstance(e.msg, RadioAltimeter)]
    n_nan = sum(math.isnan(m.h_agl_m) for m in ra)
    n_invalid = sum(not m.valid and not math.isnan(m.h_agl_m) for m in ra)  # the NaN check comes first
    assert agg["rejected"] == {"non_finite": n_nan, "ra_invalid": n_invalid} and n_nan > 0 and n_invalid > 0


def test_mc_on_flat_terrain_issues_no_fix_and_names_c3() -> None:
    result = montecarlo.run_montecarlo(terrain_scenario("flat"), 2, seed=1, workers=1, progress=False)
    agg = result["aggregate"]["estimators"]["tan1"]
    assert agg["fixes"] == 0 and agg["runs_with_fix"] == 0
    assert agg["evaluations_after_c1"] > 0 and agg["c3_false_after_c1"] == 1.0
    assert set(agg["states"]) == {"ACQUIRING", "NO_FIX_AMBIGUOUS"}


def test_mc_params_are_validated() -> None:
    doc = yaml.safe_load((REPO / "scenarios" / "terrain_nav_flat.yaml").read_text())
    doc["estimators"][0]["params"] = {"vehicle": "tan1", "config": {"mu_F": -1.0}}
    with pytest.raises(ScenarioError, match="mu_F"):
        parse_scenario(doc, "bad")
    doc["estimators"][0]["params"] = {"vehicle": "tan1", "window": 3}
    with pytest.raises(ScenarioError, match="window"):
        parse_scenario(doc, "bad")
    doc["estimators"][0]["params"] = {"vehicle": "tan9"}
    sc = parse_scenario(doc, "no such vehicle")
    with pytest.raises(ValueError, match="tan9"):
        mc.run_core([], {"vehicle": "tan9"}, sc)


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_the_truth_is_where_every_view_puts_the_true_ins_position(path: Path) -> None:
    """The report and Foxglove read a message's axes from its frame (shared/foxglove/frames.py): the truth, stamped
    with the scenario frame, must come out where the INS position (map axes, x north, z east) corrected by the
    truth's own INS errors (true = INS + d, docs/terrain_nav.md) comes out. With the scenario frame once named
    ``map`` the views swapped the truth's north and east: 8.7 km of "error" on a run whose fixes were right."""
    sc = load_scenario(path)
    ctx = FrameContext.from_scenario(sc)
    events = [e for e in scenario_events(sc, sc.seed) if e.msg.header.stamp_ns <= 20 * 10**9]
    ins = {e.msg.header.stamp_ns: e.msg for e in events if isinstance(e.msg, InsSample)}
    truths = [e for e in events if isinstance(e.msg, Truth)]
    assert truths, path
    for e in truths:
        truth, sample = e.msg, ins.get(e.msg.header.stamp_ns)
        if sample is None:  # an INS outage
            continue
        (view,) = estimates_of(e.key, truth, ctx)
        d = truth.extra
        corrected = ctx.to_enu([sample.x_m + d["dx_m"], sample.z_m + d["dz_m"], sample.h_m + d["dh_m"]], "map")
        np.testing.assert_allclose(view.position, corrected, rtol=0, atol=1e-6, err_msg=str(path))


def test_a_scenario_frame_read_with_other_axes_is_refused() -> None:
    doc = yaml.safe_load((REPO / "scenarios" / "terrain_nav_demo.yaml").read_text())
    for frame in ("map", "base_ned", "local_en_depth", "radar_nue/r1"):
        with pytest.raises(ScenarioError, match="not east, north, up"):
            parse_scenario({**doc, "frame_id": frame})
    assert parse_scenario({**doc, "frame_id": "map_enu"}).frame_id == "map_enu"
