"""Monte-Carlo runner: per-run and aggregate metrics, identical JSON for any worker count, the plugin interface."""

from __future__ import annotations

import hashlib
import importlib.machinery
import json
import subprocess
import sys
import types
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import fixstream_cmd
from pydantic import BaseModel, ConfigDict
from test_scenario_files import REPO, nav_scenario, write_scenario

from services.player.scenario import ScenarioError, load_scenario, parse_scenario
from services.player.sensor_stats import error_series
from services.player.simulators import Event
from services.player.timeline import build, player_source, scenario_events, stamp
from shared import codec, keys, plugins
from tools import montecarlo


def _small(name: str = "mc", duration_s: float = 20.0) -> dict[str, Any]:
    return nav_scenario(name=name, duration_s=duration_s)


def test_workers_1_and_2_give_identical_json(tmp_path: Path) -> None:
    path = write_scenario(tmp_path, _small(duration_s=10.0))
    scenario = load_scenario(path)
    in_process = montecarlo.dumps(montecarlo.run_montecarlo(scenario, 4, seed=9, workers=1, progress=False))
    out = tmp_path / "metrics.json"
    proc = subprocess.run(
        fixstream_cmd("mc", str(path), "--runs", "4", "--seed", "9", "--out", str(out), "--workers", "2", "--progress"),
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert "run" in proc.stderr  # the progress bar (asked for: stderr is not a terminal here)
    assert out.read_text() == in_process


def test_metrics_json_has_per_run_and_pooled_aggregate_entries(tmp_path: Path) -> None:
    scenario = parse_scenario(_small(), "mc")
    result = montecarlo.run_montecarlo(scenario, 3, seed=5, workers=1, progress=False)
    assert (result["scenario"], result["seed"], result["runs"]) == ("mc", 5, 3)
    assert [r["run"] for r in result["per_run"]] == [0, 1, 2]
    json.loads(montecarlo.dumps(result))  # plain JSON, no NaN
    key = keys.sensor("auv1", "dvl", "dvl0")
    per_run_means = [r["sensor_stats"][key]["errors"]["v_forward_mps"]["mean"] for r in result["per_run"]]
    assert len(set(per_run_means)) == 3  # runs draw different noise
    # run i is the player's run i (same events), and the pooled aggregate equals a direct computation
    pooled = []
    for i, r in enumerate(result["per_run"]):
        assert r["events"] == len(scenario_events(scenario, 5, run=i))
        sim = build(scenario, 5, run=i)
        series = error_series(list(stamp(sim.raw_events(), player_source("x"))), sim.context.platforms)
        pooled.append(series[key]["errors"]["v_forward_mps"])
    x = np.concatenate(pooled)
    agg = result["aggregate"]["sensor_stats"][key]
    assert agg["count"] == x.size == 3 * 101 and agg["type"] == "SpeedLog"
    got = agg["errors"]["v_forward_mps"]
    assert np.isclose(got["mean"], x.mean(), rtol=1e-9, atol=1e-15)
    assert np.isclose(got["sd"], x.std(ddof=1), rtol=1e-9)
    assert np.isclose(got["rms"], np.sqrt(np.mean(x * x)), rtol=1e-9)


class _FakeParams(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid")
    k: int


def _fake_run_core(events: list[Event], params: dict[str, Any], scenario: Any) -> dict[str, Any]:
    digest = hashlib.sha256(b"".join(e.key.encode() + codec.encode(e.msg) for e in events)).hexdigest()
    return {"n": len(events), "k": params["k"], "digest": digest, "source": events[0].msg.header.source}


def _fake_aggregate(per_run: list[dict[str, Any]]) -> dict[str, Any]:
    return {"runs": len(per_run), "total": sum(r["n"] for r in per_run)}


@pytest.fixture()
def fake_estimator() -> Iterator[str]:
    """An estimator package ``services.fake_mc_est`` with an mc plugin, in this process only."""
    name = "services.fake_mc_est"
    pkg = types.ModuleType(name)
    pkg.__spec__ = importlib.machinery.ModuleSpec(name, None, is_package=True)
    pkg.__path__ = []
    mc = types.ModuleType(f"{name}.mc")
    mc.__spec__ = importlib.machinery.ModuleSpec(f"{name}.mc", None)
    mc.run_core = _fake_run_core  # type: ignore[attr-defined]
    mc.aggregate = _fake_aggregate  # type: ignore[attr-defined]
    mc.Params = _FakeParams  # type: ignore[attr-defined]
    sys.modules[name], sys.modules[f"{name}.mc"] = pkg, mc
    plugins.register(plugins.Plugin(name="fake_mc_est", mc={"fake_mc_est": f"{name}.mc"}))  # = an entry point
    try:
        yield "fake_mc_est"
    finally:
        del sys.modules[name], sys.modules[f"{name}.mc"]
        plugins.plugins().pop("fake_mc_est")


def test_estimator_plugins_get_the_player_events_and_their_params(fake_estimator: str) -> None:
    doc = _small()
    doc["estimators"] = [{"kind": fake_estimator, "instance": "e1", "params": {"k": 3}}]
    scenario = parse_scenario(doc, "mc")
    result = montecarlo.run_montecarlo(scenario, 2, seed=1, workers=1, progress=False)
    for i, r in enumerate(result["per_run"]):
        expected = scenario_events(scenario, 1, run=i)
        assert r["estimators"]["e1"] == _fake_run_core(expected, {"k": 3}, scenario)
        assert r["estimators"]["e1"]["source"] == "player/default"
    assert result["aggregate"]["estimators"]["e1"] == {"runs": 2, "total": sum(r["events"] for r in result["per_run"])}
    assert result["estimators"] == [{"kind": fake_estimator, "instance": "e1"}]
    doc["estimators"][0]["params"] = {"k": "three"}
    with pytest.raises(ScenarioError, match=r"estimators\[0\]\.params\.k: Input should be a valid integer"):
        parse_scenario(doc, "mc")


def test_an_estimator_without_an_mc_plugin_is_a_clear_error() -> None:
    doc = _small()
    doc["estimators"] = [{"kind": "player"}]  # a services/ package with no mc.py
    with pytest.raises(montecarlo.MonteCarloError, match=r"'player' has no Monte-Carlo plugin"):
        montecarlo.run_montecarlo(parse_scenario(doc, "mc"), 1, workers=1, progress=False)
