"""``fixstream report FILE`` with only the file (issue 17, item 3's acceptance): a recording that carries its
scenario (attached as ``scenario/<file>.yaml`` with the ``fixstream.run`` metadata record, as the recorder writes
them) gives, copied to an empty directory and reported there, the same metrics.json as in the repository.

The recording: ``scenarios/terrain_nav_demo.yaml`` played as run 0 (:mod:`tools.report.offline`: the player's
events and the compose service's own outputs, written with the recorder's writer), then copied with the scenario
attached. terrain_nav is the estimator whose scenario names a map by a path relative to the repository
(``scenarios/maps/...``), the thing most likely to tie a report to its checkout.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
from conftest import REPO, fixstream_cmd

from services.player.scenario import load_scenario
from tools.report.offline import (
    scenario_attachment,
    scenario_feed,
    service_outputs,
    with_attachments,
    write_recording,
)

SCENARIO = REPO / "scenarios" / "terrain_nav_demo.yaml"


def _valid(msg: Any) -> bool:
    """What the recorder keeps as a message (the NaN altimeter samples it drops do not survive JSON)."""
    try:
        type(msg).model_validate_json(msg.model_dump_json())
    except ValueError:
        return False
    return True


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("portable")
    scenario = load_scenario(SCENARIO)
    feed = scenario_feed(scenario, run=0)
    outputs = service_outputs("terrain_nav-tan1", feed, REPO / "compose.yaml")
    (bare,) = write_recording(tmp / "bare", [(k, m) for k, m in feed if _valid(m)], outputs, prefix="tnd")
    carried = with_attachments(
        bare,
        tmp / "carried.mcap",
        [scenario_attachment(SCENARIO)],
        {"fixstream.run": {"scenario": scenario.name, "seed": str(scenario.seed), "run_index": "1"}},
    )
    return {"tmp": tmp, "bare": bare, "carried": carried}


@pytest.fixture(scope="module")
def in_repo(recordings: dict[str, Path]) -> dict[str, Any]:
    """The self-describing recording reported in the repository (shared by two tests: one report run)."""
    return report(recordings["carried"], recordings["tmp"] / "in_repo", cwd=REPO)


def _env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_")}


def report(recording: Path, out: Path, cwd: Path) -> dict[str, Any]:
    done = subprocess.run(
        fixstream_cmd("report", str(recording), "--out", str(out), "--no-progress", "--workers", "1"),
        cwd=cwd,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads((out / "metrics.json").read_text())


def test_a_copied_recording_reports_the_same_metrics_from_an_empty_directory(
    recordings: dict[str, Path], in_repo: dict[str, Any]
) -> None:
    tmp = recordings["tmp"]
    empty = tmp / "elsewhere"
    empty.mkdir()
    shutil.copy2(recordings["carried"], empty / "carried.mcap")  # same name: run.files gives file names
    away = report(empty / "carried.mcap", empty / "report", cwd=empty)
    assert sorted(p.name for p in empty.iterdir()) == ["carried.mcap", "report"]  # nothing else was there
    assert (tmp / "in_repo" / "metrics.json").read_text() == (empty / "report" / "metrics.json").read_text()
    assert away == in_repo
    entry = away["estimators"]["tan1"]
    assert entry["status"] == "ok" and entry["metrics"]["n_fixes"] > 0, entry.get("status")
    assert away["run"]["scenario_file"] == "scenario/terrain_nav_demo.yaml (attached to the recording)"
    assert away["run"]["recorder_run"] == 1 and away["run"]["seed"] == load_scenario(SCENARIO).seed


def test_the_attached_scenario_scores_as_the_repository_file_does(
    recordings: dict[str, Path], in_repo: dict[str, Any]
) -> None:
    """The recording without attachments, reported in the repository (the scenario looked up by name in
    scenarios/), and the self-describing copy give the same metrics, headlines and verdicts."""
    tmp = recordings["tmp"]
    looked_up = report(recordings["bare"], tmp / "bare_report", cwd=REPO)
    carried = in_repo
    assert looked_up["run"]["scenario_file"] == "scenarios/terrain_nav_demo.yaml"
    for key in ("estimators", "sections", "verdicts", "diagnostics"):
        assert carried[key] == looked_up[key], key
    assert looked_up["run"]["recorder_run"] is None and carried["run"]["metadata"] == ["fixstream.run"]


def test_without_the_attachment_an_empty_directory_says_what_is_missing(recordings: dict[str, Path]) -> None:
    empty = recordings["tmp"] / "bare_elsewhere"
    empty.mkdir()
    copy = Path(shutil.copy2(recordings["bare"], empty / recordings["bare"].name))
    got = report(copy, empty / "report", cwd=empty)
    assert got["estimators"] == {} and got["run"]["scenario_file"] is None
    assert any("not attached to the recording" in n and "--scenario" in n for n in got["notes"]), got["notes"]
    assert [s["kind"] for s in got["sections"]] == ["terrain_nav"]  # the figures are drawn all the same


def test_an_attached_scenario_that_cannot_be_read_is_said_not_called_missing(
    recordings: dict[str, Path], tmp_path: Path
) -> None:
    """A recording-reader audit: a broken scenario attachment was reported as "not attached to the recording" (the
    reason was collected and never shown)."""
    from tools.report.carried import read_carried
    from tools.report.data import find_scenario
    from tools.report.reading import read_recording

    broken = with_attachments(
        recordings["bare"], tmp_path / "broken.mcap", [("scenario/terrain_nav_demo.yaml", "application/yaml", b"[:\n")]
    )
    carried = read_carried([broken])
    choice = find_scenario(read_recording([broken], progress=False), None, tmp_path, carried)
    assert choice.scenario is None
    assert any("attachment scenario/terrain_nav_demo.yaml: not YAML" in n for n in choice.notes), choice.notes
    assert any("no readable attachment of it" in n and "--scenario" in n for n in choice.notes), choice.notes
    assert not any("not attached to the recording" in n for n in choice.notes)
