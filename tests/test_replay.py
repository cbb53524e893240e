"""MCAP replay over a real Zenoh router: the recorded messages come back byte for byte, in order, paced."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import pytest
from conftest import fixstream_cmd, wait_until
from mcap.writer import Writer
from test_player_zenoh import Collector
from test_scenario_files import REPO, nav_scenario

from services.player.scenario import parse_scenario
from services.player.simulators import Event
from services.player.timeline import scenario_events
from services.recorder.writer import RotatingMcapWriter
from shared import codec, keys
from tools.cli.main import main

pytestmark = pytest.mark.e2e

T0_NS = 1_700_000_000_000_000_000  # a wall-clock log time origin (ns, UNIX epoch)


def _events(duration_s: float) -> list[Event]:
    return scenario_events(parse_scenario(nav_scenario(name="rec", duration_s=duration_s), "rec"), 4, instance="rec")


def _record(tmp_path: Path, events: list[Event]) -> Path:
    """Write the events with the recorder's writer, log time = origin + data stamp."""
    writer = RotatingMcapWriter(tmp_path / "rec", prefix="t")
    for ev in events:
        writer.write(ev.key, ev.msg, T0_NS + ev.stamp_ns)
    writer.finish()
    (path,) = writer.files_written
    return path


def _replay(endpoint: str, path: Path, rate: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        fixstream_cmd("play", str(path), "--rate", rate, "--connect", endpoint, "--linger", "0.3"),
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=60,
    )


def test_replay_puts_the_recorded_bytes_back_in_order(router: str, tmp_path: Path) -> None:
    events = _events(20.0)
    path = _record(tmp_path, events)
    collector = Collector(router)
    try:
        time.sleep(0.3)
        proc = _replay(router, path, "0")
        assert proc.returncode == 0, proc.stderr
        assert wait_until(lambda: len(collector.samples) >= len(events), timeout=10)
        time.sleep(0.2)
        got = [(k, p, enc) for k, p, enc, _ in collector.samples]
    finally:
        collector.close()
    assert got == [(e.key, codec.encode(e.msg), codec.encoding_of(type(e.msg))) for e in events]
    assert f"replayed {len(events)} records on 5 keys" in proc.stdout and "(0 skipped)" in proc.stdout


def test_replay_paces_by_log_time_and_reports_unreadable_records(router: str, tmp_path: Path) -> None:
    events = [e for e in _events(2.0) if e.key == keys.truth("auv1")]  # 21 samples over 2 s of log time
    path = tmp_path / "mixed.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start(profile="", library="test")
        good = w.register_schema(name="fixstream.Truth", encoding="jsonschema", data=b"{}")
        bad = w.register_schema(name="fixstream.NoSuchModel", encoding="jsonschema", data=b"{}")
        good_ch = w.register_channel(topic=keys.truth("auv1"), message_encoding="json", schema_id=good)
        bad_ch = w.register_channel(topic="fixstream/sensor/auv1/x/y", message_encoding="json", schema_id=bad)
        for i, ev in enumerate(events):
            data = ev.msg.model_dump_json().encode()
            w.add_message(channel_id=good_ch, log_time=T0_NS + ev.stamp_ns, data=data, publish_time=ev.stamp_ns)
            if i == 5:
                w.add_message(
                    channel_id=bad_ch,
                    log_time=T0_NS + ev.stamp_ns,
                    data=json.dumps({}).encode(),
                    publish_time=ev.stamp_ns,
                )
        w.finish()
    collector = Collector(router)
    try:
        time.sleep(0.3)
        proc = _replay(router, path, "5")
        assert proc.returncode == 0, proc.stderr
        assert wait_until(lambda: len(collector.samples) >= len(events), timeout=10)
        samples = list(collector.samples)
    finally:
        collector.close()
    assert [p for _, p, _, _ in samples] == [codec.encode(e.msg) for e in events]
    span = samples[-1][3] - samples[0][3]  # 2 s of log time at 5x real time: 0.4 s
    assert 0.3 <= span <= 5.0, span
    assert "(1 skipped: 1 " in proc.stdout
    assert "NoSuchModel" in proc.stderr  # the skipped record is logged with its reason


def test_replay_of_a_missing_or_bad_file_exits_2(
    router: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    proc = _replay(router, bad, "0")
    assert proc.returncode == 2 and "not an MCAP file" in proc.stderr
    assert main(["play", str(tmp_path / "missing.mcap"), "--connect", router]) == 2
    assert "missing.mcap: no such file" in capsys.readouterr().err
