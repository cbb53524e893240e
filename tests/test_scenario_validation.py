"""Scenario files: good ones load, bad ones fail with a message naming the file and the field."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import pytest
from conftest import fixstream_cmd
from test_scenario_files import REPO, nav_scenario, write_scenario

from services.player.scenario import ScenarioError, load_scenario, resolve
from tools.cli.main import main


def _error(tmp_path: Path, doc: Any) -> str:
    path = tmp_path / "bad.yaml"
    if isinstance(doc, str):
        path.write_text(doc)
    else:
        write_scenario(tmp_path, doc, "bad.yaml")
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    message = str(info.value)
    assert message.startswith(str(path)), message
    return message


def test_good_file_loads_with_defaults(tmp_path: Path) -> None:
    s = load_scenario(write_scenario(tmp_path, nav_scenario()))
    assert s.name == "t" and s.duration_ns == 60_000_000_000
    assert s.wait_for == [] and s.wait_timeout_s == 30.0 and s.estimators == []
    params = s.simulator_params(0)
    assert params.model_dump()["sensors"][0]["start_s"] == 0.0  # type: ignore[index]


def test_unknown_simulator_kind_names_the_field_and_the_known_kinds(tmp_path: Path) -> None:
    doc = nav_scenario()
    doc["simulators"][0]["kind"] = "warp_drive"
    msg = _error(tmp_path, doc)
    assert "simulators[0].kind" in msg and "'warp_drive'" in msg and "nav_platform" in msg


def test_wrong_param_type_names_the_nested_field(tmp_path: Path) -> None:
    doc = nav_scenario()
    doc["simulators"][0]["params"]["truth_rate_hz"] = "fast"
    doc["simulators"][0]["params"]["sensors"][0]["sigma_mps"] = "0.1"
    msg = _error(tmp_path, doc)
    assert "simulators[0].params.truth_rate_hz" in msg
    assert "simulators[0].params.sensors[0].dvl.sigma_mps" in msg
    assert "'0.1'" in msg  # the offending value is quoted


def test_out_of_range_value(tmp_path: Path) -> None:
    doc = nav_scenario()
    doc["simulators"][0]["params"]["sensors"][2]["sigma_m"] = -1.0
    msg = _error(tmp_path, doc)
    assert "simulators[0].params.sensors[2].depth.sigma_m" in msg and "greater than or equal to 0" in msg


def test_extra_keys_are_rejected_at_every_level(tmp_path: Path) -> None:
    doc = nav_scenario()
    doc["colour"] = "red"
    doc["simulators"][0]["params"]["turbo"] = True
    doc["simulators"][0]["params"]["legs"][1]["yaw"] = 3
    msg = _error(tmp_path, doc)
    assert "colour: Extra inputs are not permitted" in msg
    assert "simulators[0].params.turbo: Extra inputs are not permitted" in msg
    assert "simulators[0].params.legs[1].yaw: Extra inputs are not permitted" in msg


def test_missing_required_fields_are_all_reported(tmp_path: Path) -> None:
    doc = nav_scenario()
    del doc["duration_s"]
    del doc["simulators"][0]["params"]["platform"]
    msg = _error(tmp_path, doc)
    assert "duration_s: Field required" in msg
    assert "simulators[0].params.platform: Field required" in msg


def test_unknown_sensor_type_and_duplicate_ids(tmp_path: Path) -> None:
    doc = nav_scenario()
    doc["simulators"][0]["params"]["sensors"].append({"type": "sonar", "id": "s0", "rate_hz": 1.0})
    msg = _error(tmp_path, doc)
    assert "simulators[0].params.sensors[4]" in msg and "'sonar'" in msg
    doc = nav_scenario()
    doc["simulators"][0]["params"]["sensors"].append(dict(doc["simulators"][0]["params"]["sensors"][0]))
    msg = _error(tmp_path, doc)
    assert "simulators[0].params: sensors[4]: a dvl sensor with id 'dvl0' is already defined" in msg
    doc = nav_scenario()
    doc["simulators"].append(dict(doc["simulators"][0]))
    msg = _error(tmp_path, doc)
    assert "simulators[1].id: duplicate simulator id 'sim1'" in msg


def test_semantic_checks(tmp_path: Path) -> None:
    doc = nav_scenario(waypoints=[{"position_m": [100.0, 0.0, -30.0]}])
    msg = _error(tmp_path, doc)
    assert "either legs or waypoints" in msg
    doc = nav_scenario(vehicle="aircraft")
    msg = _error(tmp_path, doc)
    assert "depth sensor needs vehicle: auv" in msg
    doc = nav_scenario()
    doc["wait_for"] = ["lbl_nav/a/b", "bad key"]
    msg = _error(tmp_path, doc)
    assert "wait_for[0]" in msg and "wait_for[1]" in msg
    doc = nav_scenario()
    doc["name"] = "has/slash"
    assert "name: Value error" not in _error(tmp_path, doc)  # the prefix is stripped...
    assert "name: invalid key chunk" in _error(tmp_path, doc)  # ...and the reason kept


def test_unknown_estimator_kind(tmp_path: Path) -> None:
    doc = nav_scenario()
    doc["estimators"] = [{"kind": "no_such_estimator", "instance": "a"}]
    msg = _error(tmp_path, doc)
    assert "estimators[0].kind: no installed plugin names an estimator 'no_such_estimator'" in msg
    doc["estimators"] = [{"kind": "player", "instance": "a"}, {"kind": "player", "instance": "a"}]
    msg = _error(tmp_path, doc)
    assert "estimators[1].instance: duplicate estimator instance 'a'" in msg


def test_invalid_yaml_and_wrong_top_level(tmp_path: Path) -> None:
    assert "invalid YAML" in _error(tmp_path, "name: [unclosed\n")
    assert "expected a mapping at the top level" in _error(tmp_path, "- a\n- b\n")


def test_resolve_by_path_stem_and_name(tmp_path: Path) -> None:
    path = write_scenario(tmp_path, nav_scenario(name="by_name"), "file_stem.yaml")
    assert resolve(path) == path
    assert resolve("file_stem", tmp_path) == path
    assert resolve("by_name", tmp_path) == path
    with pytest.raises(ScenarioError, match="no such scenario"):
        resolve("nothing", tmp_path)


def test_cli_validate_exit_status_and_messages(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = write_scenario(tmp_path, nav_scenario(), "good.yaml")
    doc = nav_scenario()
    doc["simulators"][0]["kind"] = "warp_drive"
    bad = write_scenario(tmp_path, doc, "bad.yaml")
    assert main(["scenarios", "validate", str(good), str(bad)]) == 1
    out = capsys.readouterr().out
    assert f"{good}: OK" in out
    assert f"{bad}: simulators[0].kind: unknown simulator kind 'warp_drive'" in out
    assert main(["scenarios", "validate", str(good)]) == 0
    assert main(["scenarios", "validate", "--dir", str(REPO / "scenarios")]) == 0  # every shipped file


def test_cli_show_lists_the_streams(capsys: pytest.CaptureFixture[str]) -> None:
    proc = subprocess.run(
        fixstream_cmd("scenarios", "show", "demo", "--dir", str(REPO / "scenarios")),
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert proc.returncode == 0, proc.stderr
    assert "fixstream/sensor/auv1/dvl/dvl0" in proc.stdout and "SpeedLog" in proc.stdout
    assert "report_velocity: true" in proc.stdout  # defaults are filled in
