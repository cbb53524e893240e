"""End to end: ``fixstream up`` on the repository's compose.yaml (router, recorder, player) writes an MCAP
holding the scenario's truth and sensor streams. Scenario and recordings are redirected into tmp_path."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from collections import Counter
from pathlib import Path

import pytest
import yaml
from conftest import REPO, fixstream_cmd
from mcap.reader import make_reader


@pytest.mark.e2e
def test_up_records_the_demo_scenario(tmp_path: Path) -> None:
    scenario = tmp_path / "scenario.yaml"
    shutil.copy(REPO / "scenarios" / "demo.yaml", scenario)
    spec = yaml.safe_load(scenario.read_text())
    platforms = {sim["params"]["platform"] for sim in spec["simulators"] if "platform" in sim["params"]}
    recordings = tmp_path / "recordings"
    env = {k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_")}
    env.update({"FIXSTREAM_SCENARIO": str(scenario), "FIXSTREAM_RATE": "0"})

    proc = subprocess.run(
        fixstream_cmd("up", "-f", str(REPO / "compose.yaml"), "--recordings", str(recordings), "--no-color"),
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=180,
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    assert "[up] recorder ready: fixstream/alive/recorder/main" in out
    assert out.index("[up] recorder ready") < out.index("[up] player started")
    assert out.index("stopping recorder (SIGTERM)") < out.index("stopping router (SIGTERM)")

    files = sorted(recordings.glob("*.mcap"))
    assert len(files) == 1, out
    assert f"[up] recording: {files[0]}" in out
    with files[0].open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()  # finalised on SIGTERM: summary and footer written
        assert summary is not None
        counts: Counter[str] = Counter()
        recorder_diags = []
        for _, channel, message in reader.iter_messages():
            counts[channel.topic] += 1
            if channel.topic == "fixstream/diag/recorder/main":
                recorder_diags.append(json.loads(message.data))
    for platform in platforms:
        assert counts[f"fixstream/truth/{platform}"] > 0, counts
        assert any(k.startswith(f"fixstream/sensor/{platform}/") for k in counts), counts
    # the demo's estimators answered: terrain verdicts and fixes, one PCL report per scan and pair
    for key in (
        "fixstream/fix/terrain/tan1/verdict",
        "fixstream/fix/terrain/tan1",
        "fixstream/track/pcl/rx1/tx-fm-98.1",
        "fixstream/track/pcl/rx1/tx-dvbt-530",
    ):
        assert counts[key] > 0, (key, sorted(counts))
    assert counts["fixstream/track/pcl/rx1/tx-fm-98.1"] == counts["fixstream/sensor/rx1/pcl/tx-fm-98.1"]
    published = re.search(r"published (\d+) messages", out)
    assert published is not None, out
    # the player publishes sensors, truth and the group's uplink requests to the coordinator (the closed loop)
    player_keys = ("fixstream/truth/", "fixstream/sensor/")
    streams = sum(
        n for k, n in counts.items() if k.startswith(player_keys) or k.startswith("fixstream/group/group1/uplink/")
    )
    # the demo publishes a few deliberately invalid samples (NaN) that the recorder refuses, reports and keeps byte
    # for byte on fixstream/rejected/<key>: everything the player published is in the file, nothing lost, and the
    # player's streams show no seq gap (a refused sample is recorded, not dropped)
    refused = max((d["count"] for d in recorder_diags if d["reason"] == "non_finite"), default=0)
    gaps = max((d["count"] for d in recorder_diags if d["reason"] == "seq_gap"), default=0)
    kept_raw = sum(n for k, n in counts.items() if k.startswith("fixstream/rejected/fixstream/sensor/"))
    # the scenario names how many NaN samples it publishes; every one is kept raw. The recorder's diagnostics are
    # rate-limited per reason (counts are never lost, messages may be), so the last one recorded may be behind
    nan_samples = sum(int(sim["params"].get("nan_samples", 0)) for sim in spec["simulators"])
    assert nan_samples > 0 and kept_raw == nan_samples
    assert 0 < refused <= kept_raw, "the demo's NaN samples were not refused"
    assert gaps == 0
    assert streams + kept_raw == int(published.group(1))
    assert {d["reason"] for d in recorder_diags} <= {"non_finite", "seq_gap"}, [d["reason"] for d in recorder_diags]
    assert not (REPO / "recordings").exists() or not any(
        p.stat().st_mtime > files[0].stat().st_mtime - 60 for p in (REPO / "recordings").glob("*.mcap")
    )
