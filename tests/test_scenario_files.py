"""The shipped scenario files validate, the docs cover every parameter; helpers for the other scenario tests."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel

from services.player.scenario import Scenario, load_scenario, scenario_files
from services.player.simulators.nav_platform import NavPlatformParams
from services.player.simulators.sensors import DepthParams, HeadingParams, InsParams, SpeedLogParams
from services.player.simulators.trajectory import Leg, StartState, Waypoint

REPO = Path(__file__).resolve().parent.parent

BASE_PLATFORM: dict[str, Any] = {
    "platform": "auv1",
    "vehicle": "auv",
    "truth_rate_hz": 10.0,
    "start": {"position_m": [0.0, 0.0, -30.0], "heading_deg": 45.0, "speed_mps": 2.0},
    "legs": [
        {"duration_s": 15.0},
        {"duration_s": 15.0, "turn_rate_dps": 6.0, "climb_rate_mps": -0.4},
        {"duration_s": 15.0},
    ],
    "sensors": [
        {"type": "dvl", "id": "dvl0", "rate_hz": 5.0, "sigma_mps": 0.01, "bias_mps": [0.005, 0.0, 0.0]},
        {"type": "heading", "id": "gyro0", "rate_hz": 10.0, "bias_deg": 0.5, "gm_sigma_deg": 1.0, "gm_tau_s": 300.0},
        {"type": "depth", "id": "press0", "rate_hz": 2.0, "sigma_m": 0.05},
        {"type": "ins", "id": "ins0", "rate_hz": 10.0, "initial_sigma_m": 2.0, "drift_m_per_sqrt_s": 0.05},
    ],
}


def nav_scenario(name: str = "t", duration_s: float = 60.0, **platform: Any) -> dict[str, Any]:
    """A scenario document with one nav_platform simulator; keyword arguments replace its params."""
    params = copy.deepcopy(BASE_PLATFORM)
    params.update(platform)
    return {
        "name": name,
        "seed": 7,
        "duration_s": duration_s,
        "frame_id": "local_enu",
        "simulators": [{"kind": "nav_platform", "id": "sim1", "params": params}],
    }


def write_scenario(tmp_path: Path, doc: dict[str, Any], filename: str = "s.yaml") -> Path:
    path = tmp_path / filename
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_every_shipped_scenario_validates() -> None:
    files = scenario_files(REPO / "scenarios")
    assert [f.name for f in files if f.name == "demo.yaml"] == ["demo.yaml"]
    for f in files:
        assert isinstance(load_scenario(f), Scenario)


def test_demo_has_every_sensor_type_and_sixty_seconds() -> None:
    s = load_scenario(REPO / "scenarios" / "demo.yaml")
    params = s.simulator_params(0)
    assert isinstance(params, NavPlatformParams)
    assert {sensor.type for sensor in params.sensors} == {"dvl", "speed_log", "heading", "depth", "ins"}
    assert s.duration_s == 60.0


def _field_names(*models: type[BaseModel]) -> set[str]:
    return {name for m in models for name in m.model_fields}


def test_docs_name_every_parameter() -> None:
    text = (REPO / "docs" / "scenarios.md").read_text()
    names = _field_names(Scenario, NavPlatformParams, StartState, Leg, Waypoint) | _field_names(
        SpeedLogParams, HeadingParams, DepthParams, InsParams
    )
    missing = sorted(n for n in names if f"`{n}`" not in text)
    assert missing == []
    for kind in ("dvl", "speed_log", "heading", "depth", "ins", "nav_platform", "sensor_stats"):
        assert f"`{kind}`" in text
