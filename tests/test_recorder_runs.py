"""Recordings of scenario runs over real processes: the same data-clock timeline whatever the playback rate, and a
file that describes itself (metadata, the scenario as an attachment, ``fixstream info``)."""

from __future__ import annotations

import json
import re
import subprocess
import time
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
import yaml
from conftest import REPO, fixstream_cmd, wait_until
from recorder_support import recorder
from test_player_zenoh import Collector
from test_scenario_files import nav_scenario

from services.player.scenario import parse_scenario
from services.player.timeline import scenario_events
from shared import keys
from shared.mcap_io import recording_files, scan

pytestmark = pytest.mark.e2e


def _record_run(router: str, tmp_path: Path, scenario: Path, rate: str, instance: str) -> Path:
    """Play the scenario at ``rate`` into a fresh recorder; returns the finalised file."""
    env = {"FIXSTREAM_RECORDER_SCENARIOS_DIR": str(scenario.parent)}
    (tmp_path / instance).mkdir()
    with recorder(router, tmp_path / instance, instance=instance, **env) as rec:
        done = subprocess.run(
            fixstream_cmd(
                "play", str(scenario), "--rate", rate, "--connect", router, "--wait-for", f"recorder/{instance}"
            ),
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode == 0, done.stderr
        rec.wait_status(lambda s: s["services_seen"] >= 1 and s["runs"] == {scenario.stem: 1})
        rec.wait_status(lambda s: s["counters"]["received"] >= _expected_total(scenario))
        rec.terminate()
    (path,) = recording_files(rec.out_dir)
    return path


def _expected(scenario: Path) -> dict[str, tuple[int, int, int]]:
    """Per key: (count, first stamp, last stamp) of what the player publishes, computed in-process."""
    sc = parse_scenario(yaml.safe_load(scenario.read_text()), str(scenario))
    events = scenario_events(sc, sc.seed)
    out: dict[str, tuple[int, int, int]] = {}
    counts = Counter(ev.key for ev in events)
    for ev in events:
        _, first, last = out.get(ev.key, (0, ev.stamp_ns, ev.stamp_ns))
        out[ev.key] = (counts[ev.key], min(first, ev.stamp_ns), max(last, ev.stamp_ns))
    last = max(ev.stamp_ns for ev in events)
    out[keys.scenario(sc.name)] = (2, 0, last)  # start marker at 0, end marker at the last stamp
    return out


def _expected_total(scenario: Path) -> int:
    return sum(n for n, _, _ in _expected(scenario).values())


def _timeline(info: Any) -> dict[str, tuple[int, int, int]]:
    return {t: (v.count, v.first_ns, v.last_ns) for t, v in info.topics.items() if not t.startswith("fixstream/diag")}


def test_rate_0_and_rate_5_record_one_data_clock_timeline(router: str, tmp_path: Path) -> None:
    scen_dir = tmp_path / "scenarios"
    scen_dir.mkdir()
    scenario = scen_dir / "clock.yaml"
    scenario.write_text(yaml.safe_dump(nav_scenario(name="clock", duration_s=2.0), sort_keys=False))
    expected = _expected(scenario)
    fast = scan(_record_run(router, tmp_path, scenario, "0", "r0"))
    paced = scan(_record_run(router, tmp_path, scenario, "5", "r5"))
    assert _timeline(fast) == _timeline(paced) == expected
    first = min(f for _, f, _ in expected.values())
    last = max(la for _, _, la in expected.values())
    for info in (fast, paced):
        assert info.finalised and (info.start_ns, info.end_ns) == (first, last)
        assert {a.name: a.data for a in info.attachments} == {"scenario/clock.yaml": scenario.read_bytes()}
        meta = {m.name: dict(m.metadata) for m in info.metadata}
        run = meta["fixstream.run"]
        assert (run["scenario"], run["seed"], run["run_index"], run["player"]) == ("clock", "7", "1", "player/default")
        assert meta["fixstream.recorder"]["fixstream_version"] not in ("", "unknown")
        services = {k: json.loads(v) for k, v in meta["fixstream.services"].items()}
        (mine,) = [v for k, v in services.items() if k.startswith("recorder/")]
        assert mine["config"]["key_expr"] == "fixstream/**"

    done = subprocess.run(fixstream_cmd("info", str(paced.path)), cwd=REPO, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    text = done.stdout
    assert f"Duration:         {(last - first) / 1e9:.3f} s on the data clock" in text
    assert "State:            finalised" in text and "scenario/clock.yaml" in text and "fixstream.run:" in text
    for key, (n, f, la) in expected.items():
        rate = (n - 1) / ((la - f) / 1e9) if n > 1 and la > f else 0.0
        assert any(line.split()[:3] == [key, str(n), f"{rate:.2f}"] for line in text.splitlines()), key
    as_json = subprocess.run(fixstream_cmd("info", "--json", str(fast.path)), cwd=REPO, capture_output=True, text=True)
    doc = json.loads(as_json.stdout)
    assert doc["state"] == "finalised" and doc["messages"] == fast.messages


def test_a_recording_at_rate_0_replays_at_rate_1_in_the_scenario_duration(router: str, tmp_path: Path) -> None:
    """Recorded as fast as possible, replayed at ``--rate 1``: from the first to the last message a subscriber
    receives, the wall time is the data-clock duration (the player's stamps, computed in-process) within 5 %, and
    so is the time the player reports."""
    scen_dir = tmp_path / "scenarios"
    scen_dir.mkdir()
    scenario = scen_dir / "paced.yaml"
    scenario.write_text(yaml.safe_dump(nav_scenario(name="paced", duration_s=6.0), sort_keys=False))
    expected = _expected(scenario)
    duration_s = (max(la for _, _, la in expected.values()) - min(f for _, f, _ in expected.values())) / 1e9
    path = _record_run(router, tmp_path, scenario, "0", "r0")
    assert (scan(path).end_ns - scan(path).start_ns) / 1e9 == duration_s  # the file's timeline is the data clock

    collector = Collector(router)
    try:
        time.sleep(0.3)  # the subscription reaches the router before the player starts
        done = subprocess.run(
            fixstream_cmd("play", str(path), "--rate", "1", "--connect", router, "--linger", "0.3"),
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert done.returncode == 0, done.stderr
        n = sum(count for count, _, _ in expected.values())
        assert wait_until(lambda: len(collector.samples) >= n, timeout=10), (len(collector.samples), n)
        arrivals = [t for key, _, _, t in collector.samples if not key.startswith(f"{keys.ROOT}/diag/")]
    finally:
        collector.close()
    assert len(arrivals) == n
    wall_s = arrivals[-1] - arrivals[0]
    reported = re.search(r" in (\d+\.\d+) s", done.stdout)
    assert reported is not None, done.stdout
    reported_s = float(reported.group(1))
    print(f"\ndata clock {duration_s:.3f} s, subscriber {wall_s:.3f} s, player {reported_s:.2f} s")
    assert abs(wall_s - duration_s) <= 0.05 * duration_s, (wall_s, duration_s)
    assert abs(reported_s - duration_s) <= 0.05 * duration_s, (reported_s, duration_s)
