"""Acceptance of the streaming backbone over real processes and a real router on loopback ports.

player -> router -> recorder: the MCAP holds exactly the published count per channel and every
message equals the one the scenario produces in-process; then ``fixstream play`` of that MCAP into a
second recorder gives the same messages again.
"""

from __future__ import annotations

import subprocess
from collections import defaultdict
from pathlib import Path

import pytest
import yaml
from conftest import REPO, fixstream_cmd, service_env

from schemas import Message, ScenarioMarker
from services.player.scenario import load_scenario
from services.player.timeline import scenario_events
from shared.mcap_io import decode_record, iter_records, recording_files

pytestmark = pytest.mark.e2e

DEMO = REPO / "scenarios" / "demo.yaml"


def platform_scenario(tmp_path: Path) -> Path:
    """The demo's built-in nav_platform part alone (the estimators' parts need their services)."""
    doc = yaml.safe_load(DEMO.read_text())
    doc["simulators"] = [s for s in doc["simulators"] if s["kind"] == "nav_platform"]
    doc["wait_for"], doc["estimators"] = [], []
    path = tmp_path / "platform.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def start_recorder(endpoint: str, out_dir: Path, instance: str) -> subprocess.Popen[str]:
    env = service_env(
        endpoint,
        FIXSTREAM_RECORDER_INSTANCE=instance,
        FIXSTREAM_RECORDER_OUT_DIR=str(out_dir),
        FIXSTREAM_RECORDER_KEY_EXPR="fixstream/**",
    )
    return subprocess.Popen(fixstream_cmd("run", "recorder"), env=env, cwd=REPO, text=True)


def stop(proc: subprocess.Popen[str]) -> None:
    proc.terminate()
    assert proc.wait(timeout=30) == 0


def play(endpoint: str, target: Path, *extra: str) -> None:
    done = subprocess.run(
        fixstream_cmd("play", str(target), "--rate", "0", *extra),
        env=service_env(endpoint),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-3000:]


def read_dir(out_dir: Path) -> dict[str, list[Message]]:
    """Every recorded message by channel, in file order."""
    by_topic: dict[str, list[Message]] = defaultdict(list)
    files = recording_files(out_dir)
    assert files, f"no MCAP written in {out_dir}"
    for f in files:
        for rec in iter_records(f):
            by_topic[rec.topic].append(decode_record(rec))
    return dict(by_topic)


def test_player_recorder_replay_round_trip(router: str, tmp_path: Path) -> None:
    scenario_file = platform_scenario(tmp_path)
    scenario = load_scenario(scenario_file)
    expected: dict[str, list[Message]] = defaultdict(list)
    for ev in scenario_events(scenario):  # the same pure function the player publishes from
        expected[ev.key].append(ev.msg)

    # 1. play the scenario into recorder A (the player waits for the recorder's liveliness token)
    rec_a = start_recorder(router, tmp_path / "a", "a")
    try:
        play(router, scenario_file, "--wait-for", "recorder/a")
    finally:
        stop(rec_a)
    got_a = read_dir(tmp_path / "a")

    markers = got_a.pop(f"fixstream/scenario/{scenario.name}")
    assert [m.event for m in markers] == ["start", "end"]  # type: ignore[attr-defined]
    end = markers[-1]
    assert isinstance(end, ScenarioMarker)
    data_a = {k: v for k, v in got_a.items() if not k.startswith("fixstream/diag/")}
    # exactly the published count per channel, and the player's own count agrees
    assert {k: len(v) for k, v in data_a.items()} == {k: len(v) for k, v in expected.items()}
    assert end.published == {k: len(v) for k, v in expected.items()}
    # each message decodes to the model that was sent, equal field for field (header included)
    for key, msgs in expected.items():
        assert data_a[key] == msgs, f"messages differ on {key}"

    # 2. replay the MCAP into recorder B: the same messages again
    rec_b = start_recorder(router, tmp_path / "b", "b")
    try:
        play(router, recording_files(tmp_path / "a")[0], "--wait-for", "recorder/b")
    finally:
        stop(rec_b)
    got_b = read_dir(tmp_path / "b")
    replayed = {k: v for k, v in got_b.items() if not k.startswith("fixstream/diag/recorder/b")}
    original = {k: v for k, v in read_dir(tmp_path / "a").items()}
    assert replayed == original
