"""Two Zenoh routers meshed on loopback carry a run exactly as one router does (issue 18, item 5).

Router A listens; router B listens and connects to A (``fixstream router --connect``). The recorder and the player
are clients of A, the estimators clients of B: every sensor message crosses the mesh A -> B, every fix and
diagnostic B -> A, the liveliness tokens the player waits for B -> A, and the AUV group's closed loop (the player's
interactive simulator asks the coordinator, ``docs/scenarios.md``) both ways within the run. The same scenario on
one router is the reference.

What is compared: every recorded message, decoded, per channel and in order (``recorded_by_topic``), header
included. Nothing is left out of the messages themselves: no fixstream message carries a receive time. What
differs between two runs lives outside them: the order of messages *across* channels, which Zenoh does not define
(each key keeps its publisher's order; different keys can interleave differently on different routes).

Scenario: ``rd_demo`` (AUV group navigation, digest 002): three services (``coordinator-group1``,
``rd_nav-auv3``, ``rd_nav-auv4``) as the repository's compose.yaml configures them.
"""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import pytest
from conftest import REPO, fixstream_cmd, running_router
from stack_support import COMPOSE, recorded_by_topic, stack_env

from schemas import Message
from shared import keys
from shared.session import open_session
from shared.settings import ZenohSettings
from tools.stack import load_compose

pytestmark = pytest.mark.e2e

SCENARIO = REPO / "scenarios" / "rd_demo.yaml"
ESTIMATORS = ["coordinator-group1", "rd_nav-auv3", "rd_nav-auv4"]


def _composed(service: str, endpoint: str, out_dir: Path) -> tuple[list[str], dict[str, str]]:
    """The compose service's command and environment, as a client of the router at ``endpoint``."""
    spec = load_compose(COMPOSE, environ=stack_env(SCENARIO)).services[service]
    env = stack_env(SCENARIO)
    env.update({k: v for k, v in spec.environment.items() if v is not None})
    env.update(
        {
            "FIXSTREAM_ZENOH_CONNECT": endpoint,
            "FIXSTREAM_RECORDER_OUT_DIR": str(out_dir),
            "FIXSTREAM_LOG_LEVEL": "WARNING",
        }
    )
    assert spec.command[0] == "fixstream"
    return fixstream_cmd(*spec.command[1:]), env


def _until_recorder_quiet(endpoint: str, quiet_s: float = 1.5, timeout_s: float = 30.0) -> None:
    """Wait until the recorder's ``written`` count (its status) has not moved for ``quiet_s``: the estimators'
    last outputs (flushed at the end marker) are in before the processes are stopped."""
    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    try:
        last, since = -1, time.monotonic()
        deadline = since + timeout_s
        while time.monotonic() < deadline:
            replies = [r.ok for r in session.get(keys.status("recorder", "main"), timeout=5.0) if r.ok is not None]
            written = int(json.loads(replies[0].payload.to_bytes()).get("written", -1)) if replies else -1
            if written != last:
                last, since = written, time.monotonic()
            elif time.monotonic() - since >= quiet_s:
                return
            time.sleep(0.25)
    finally:
        session.close()


def run(player_side: str, estimator_side: str, out_dir: Path) -> dict[str, list[Message]]:
    """Recorder and player on ``player_side``, the estimators on ``estimator_side``; the recording per channel."""
    procs = []
    try:
        for service, endpoint in [("recorder", player_side), *((e, estimator_side) for e in ESTIMATORS)]:
            cmd, env = _composed(service, endpoint, out_dir)
            procs.append(subprocess.Popen(cmd, env=env, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE))
        cmd, env = _composed("player", player_side, out_dir)
        played = subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True, timeout=240)
        assert played.returncode == 0, played.stderr[-3000:]
        _until_recorder_quiet(player_side)
    finally:
        for proc in procs:
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
    return recorded_by_topic(out_dir)


def test_two_meshed_routers_record_what_one_router_records(tmp_path: Path) -> None:
    with running_router() as single:
        reference = run(single, single, tmp_path / "single")
    with running_router() as a, running_router(a) as b:
        meshed = run(a, b, tmp_path / "mesh")

    # the run reached every side: sensors, the group's closed loop (assignments) and the fixes of both AUVs
    topics = set(reference)
    assert any(t.startswith("fixstream/sensor/") for t in topics)
    assert {"fixstream/fix/rd/auv3", "fixstream/fix/rd/auv4"} <= topics, sorted(topics)
    assert any(t.startswith("fixstream/group/group1/") for t in topics), sorted(topics)
    assert sorted(meshed) == sorted(reference)
    for topic, messages in reference.items():
        assert meshed[topic] == messages, f"{topic}: {len(meshed[topic])} messages vs {len(messages)} on one router"
