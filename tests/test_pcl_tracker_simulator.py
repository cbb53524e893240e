"""PCL tracker player plugin (``kind: pcl_tracker``), the scenario files and the Monte-Carlo plugin."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from conftest import REPO, fixstream_cmd

from schemas import Truth
from schemas.radar import BistaticScan
from services.pcl_tracker import mc
from services.pcl_tracker.core import PclTracker
from services.pcl_tracker.metrics import run_metrics
from services.pcl_tracker.simulation import paper_scenario, simulate
from services.pcl_tracker.simulator import PclSimParams, PclSimulator
from services.player.scenario import ScenarioError, load_scenario, parse_scenario
from services.player.simulators import ScenarioContext, child_seed
from services.player.timeline import run_seed, scenario_events

SCENARIOS = sorted((REPO / "scenarios").glob("pcl_tracker_*.yaml"))


def paper_spec() -> dict[str, Any]:
    return yaml.safe_load((REPO / "scenarios" / "pcl_tracker_paper.yaml").read_text())  # type: ignore[no-any-return]


def test_the_issue_scenarios_exist_and_load() -> None:
    names = {p.stem for p in SCENARIOS}
    assert {"pcl_tracker_paper", "pcl_tracker_clutter", "pcl_tracker_many", "pcl_tracker_demo"} <= names
    for p in SCENARIOS:
        sc = load_scenario(p)
        assert sc.name == p.stem
        assert sc.wait_for and all(w.startswith("pcl_tracker/") for w in sc.wait_for)
        assert {e.kind for e in sc.estimators} == {"pcl_tracker"}
    assert load_scenario(REPO / "scenarios" / "pcl_tracker_demo.yaml").duration_s <= 60.0


def test_plugin_events_are_the_core_simulation() -> None:
    """The plugin adds nothing to the core's simulation: the same generator gives the same plots and truth."""
    sc = load_scenario(REPO / "scenarios" / "pcl_tracker_paper.yaml")
    events = scenario_events(sc)
    scans = [e.msg for e in events if isinstance(e.msg, BistaticScan)]
    truths = [e for e in events if isinstance(e.msg, Truth)]
    assert [s.scan_id for s in scans] == list(range(1, 52))
    assert [s.header.stamp_ns for s in scans] == [k * 3_000_000_000 for k in range(51)]
    assert {e.key for e in truths} == {"fixstream/truth/target1"}
    assert {e.key for e in events} - {"fixstream/truth/target1"} == {"fixstream/sensor/rx1/pcl/tx-fm-98.1"}
    # the simulator's generator is the child keyed by its id under the run's seed sequence
    rng = np.random.Generator(np.random.PCG64(child_seed(run_seed(sc.seed), sc.simulators[0].id)))
    ref = simulate(paper_scenario(), rng)
    for got, exp in zip(scans, ref.scans, strict=True):
        assert got.model_dump(exclude={"header"}) == exp.model_dump(exclude={"header"})
        assert got.header.frame_id == "pcl_enu" and got.header.source == "player/default"
    for k, e in enumerate(truths):
        assert isinstance(e.msg, Truth)
        np.testing.assert_array_equal(e.msg.position_m, ref.true_states[k, 0, :3])
        np.testing.assert_array_equal(e.msg.velocity_mps, ref.true_states[k, 0, 3:])


def test_targets_live_on_the_scenario_clock_and_truth_can_be_switched_off() -> None:
    spec = paper_spec()
    p = spec["simulators"][0]["params"]
    p["scan_period_s"] = 2.0
    p["start_s"] = 1.0
    p["targets"].append({"id": "late", "position_m": [20000, 0, 500], "velocity_mps": [0, 100, 0], "birth_s": 20})
    spec["duration_s"] = 40
    events = scenario_events(parse_scenario(spec))
    stamps = sorted({e.stamp_ns for e in events})
    assert stamps[0] == 1_000_000_000 and stamps[-1] == 39_000_000_000 and len(stamps) == 20
    late = [e for e in events if e.key == "fixstream/truth/late"]
    assert late[0].stamp_ns == 21_000_000_000
    assert isinstance(late[0].msg, Truth) and late[0].msg.position_m == pytest.approx([20000.0, 100.0, 500.0])
    # a second pair seeing the same targets publishes scans only, and registers no platforms
    params = PclSimParams.model_validate({**p, "publish_truth": False}, strict=True)
    ctx = ScenarioContext("x", "pcl_enu", 40_000_000_000, 0)
    sim = PclSimulator(params, np.random.default_rng(0), ctx)
    assert {e.key for e in sim.events()} == {"fixstream/sensor/rx1/pcl/tx-fm-98.1"} and ctx.platforms == {}
    ctx2 = ScenarioContext("x", "pcl_enu", 40_000_000_000, 0)
    PclSimulator(PclSimParams.model_validate(p, strict=True), np.random.default_rng(0), ctx2)
    truth = ctx2.platforms["late"].truth_at(np.array([0, 21_000_000_000]))
    assert np.isnan(truth.position_m[0]).all() and truth.position_m[1] == pytest.approx([20000.0, 100.0, 500.0])
    assert truth.heading_rad[1] == pytest.approx(0.0)


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (("sigma", "rb_m"), -1.0, "simulators[0].params.sigma.rb_m"),
        (("p_detection",), 1.5, "simulators[0].params.p_detection"),
        (("clutter", "rb_range_m"), [5.0, 1.0], "rb_range_m"),
        (("targets", 0, "id"), "bad/id", "simulators[0].params.targets[0].id"),
        (("targets", 0, "velocity_mps"), [1.0, 2.0, 3.0], "exactly one of velocity_mps and speed_mps"),
        (("tx_position_enu_m",), [1.0, 2.0], "simulators[0].params.tx_position_enu_m"),
        (("range_form",), "phase", "simulators[0].params.range_form"),
        (("unknown_field",), 1, "unknown_field"),
    ],
)
def test_parameter_errors_name_the_field(path: tuple[Any, ...], value: Any, message: str) -> None:
    spec = paper_spec()
    node = spec["simulators"][0]["params"]
    for part in path[:-1]:
        node = node.setdefault(part, {}) if isinstance(node, dict) else node[part]
    node[path[-1]] = value
    with pytest.raises(ScenarioError, match=message.replace("[", r"\[").replace("]", r"\]")):
        parse_scenario(spec, "x.yaml")


def test_estimator_params_are_checked_by_the_mc_plugin() -> None:
    spec = paper_spec()
    spec["estimators"][0]["params"]["confirm_Q"] = 3
    with pytest.raises(ScenarioError, match="confirm_Q"):
        parse_scenario(spec, "x.yaml")


def test_mc_run_core_is_the_core_over_the_events() -> None:
    spec = yaml.safe_load((REPO / "scenarios" / "pcl_tracker_clutter.yaml").read_text())
    spec["duration_s"] = 45
    sc = parse_scenario(spec)
    events = scenario_events(sc, run=0)
    params = dict(sc.estimators[0].params)  # the default configuration (M/N = 3/4)
    got = mc.run_core(events, params, sc)
    core = PclTracker(mc.to_config(mc.Params.model_validate(params, strict=True)))
    reps = [r for e in events if isinstance(e.msg, BistaticScan) for r in core.step(e.msg)]
    truth = np.array([[[*e.msg.position_m, *e.msg.velocity_mps]] for e in events if isinstance(e.msg, Truth)])  # type: ignore[union-attr]
    ref = run_metrics(reps, truth, [r.scan_id for r in reps])
    for k, v in ref.items():
        assert got[k] == v, k
    assert got["targets"] == ["target1"] and got["n_scans"] == 16
    assert got["t_s"] == [3.0 * k for k in range(16)]


def test_fixstream_mc_writes_the_metrics_independent_of_workers(tmp_path: Path) -> None:
    spec = yaml.safe_load((REPO / "scenarios" / "pcl_tracker_clutter.yaml").read_text())
    spec["duration_s"] = 60
    scenario = tmp_path / "pcl_small.yaml"
    scenario.write_text(yaml.safe_dump(spec))
    outs = []
    for workers in (1, 2):
        out = tmp_path / f"mc{workers}.json"
        done = subprocess.run(
            fixstream_cmd(
                "mc", str(scenario), "--runs", "3", "--seed", "5", "--out", str(out), "--workers", str(workers)
            ),
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert done.returncode == 0, done.stderr[-3000:]
        outs.append(out.read_bytes())
    assert outs[0] == outs[1]
    result = json.loads(outs[0])
    assert [e["instance"] for e in result["estimators"]] == ["rx1-fm", "rx1-fm-paper"]
    for inst in ("rx1-fm", "rx1-fm-paper"):
        agg = result["aggregate"]["estimators"][inst]
        # the issue's metrics: RMSE over time, continuity, false confirmed tracks per run, OSPA per scan
        for key in ("pos_rmse_m", "vel_rmse_mps", "ospa_mean_m_per_scan", "t_s"):
            assert len(agg[key]) == 21, key
        for key in ("id_swaps_per_run", "breaks_per_run", "false_confirmed_tracks_per_run", "coverage"):
            assert isinstance(agg[key], float), key
        assert agg["n_runs"] == 3
        assert agg["pos_rmse_m"][0] is None and 0.0 < agg["pos_rmse_m"][-1] < 250.0
        per_run = [r["estimators"][inst] for r in result["per_run"]]
        assert [len(r["ospa_m"]) for r in per_run] == [21, 21, 21]
        assert agg["false_confirmed_tracks_per_run"] == pytest.approx(
            np.mean([r["false_confirmed_tracks"] for r in per_run])
        )
    mn, fm = (result["aggregate"]["estimators"][i] for i in ("rx1-fm", "rx1-fm-paper"))
    assert fm["false_confirmed_tracks_per_run"] > 3.0  # paper: M = 0 confirms false pairs (digest E5: ~42 in 150 s)
    assert mn["false_confirmed_tracks_per_run"] <= 0.5  # default: M/N = 3/4 does not (digest: <= 0.1)


def test_many_target_scenario_through_the_plugin() -> None:
    """Range-sum and Doppler plots of 20 targets through the DVB-T pair: all tracked, no false track."""
    spec = yaml.safe_load((REPO / "scenarios" / "pcl_tracker_many.yaml").read_text())
    sc = parse_scenario(spec)
    agg = mc.aggregate([mc.run_core(scenario_events(sc, run=r), dict(sc.estimators[0].params), sc) for r in range(2)])
    assert agg["final_track_fraction"] >= 0.95 and agg["coverage"] >= 0.85
    assert agg["false_confirmed_tracks_per_run"] <= 1.0 and agg["id_swaps_per_run"] <= 1.0
