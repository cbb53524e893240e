"""A recorded scenario run waits for the recorder, whatever the scenario's ``wait_for`` says (issue 13 item 5).

Under compose nothing else orders the player after the recorder's subscription: ``depends_on`` only orders
container starts. compose.yaml therefore gives the player ``--wait-for recorder/main``. These tests run the
router, the player and the recorder as real processes with exactly the commands and environment compose.yaml
gives them (``fixstream up``'s plan of it), but start them by hand, in the order a slow container start can
produce: the player first, the recorder seconds later (or never).
"""

from __future__ import annotations

import os
import subprocess
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import REPO, wait_until

from schemas import ScenarioMarker
from shared.mcap_io import decode_record, iter_records
from tools.stack import load_compose, plan_stack
from tools.stack.plan import ProcessSpec
from tools.stack.readiness import port_open

#: like the four PCL scenarios: the recorder is not in wait_for (nothing is)
SCENARIO = """\
format: 1
name: late_recorder
duration_s: 20
wait_timeout_s: {timeout}
simulators:
  - kind: nav_platform
    id: auv1
    params:
      platform: auv1
      vehicle: auv
      truth_rate_hz: 10
      start: {{position_m: [0.0, 0.0, -30.0], heading_deg: 45.0, speed_mps: 2.0}}
      legs:
        - {{duration_s: 20}}
      sensors:
        - {{type: depth, id: press0, rate_hz: 5, sigma_m: 0.05}}
        - {{type: speed_log, id: log0, rate_hz: 1, sigma_mps: 0.1}}
"""


def compose_processes(tmp_path: Path, timeout_s: float) -> dict[str, ProcessSpec]:
    scenario = tmp_path / "late_recorder.yaml"
    scenario.write_text(SCENARIO.format(timeout=timeout_s))
    env = {k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_")}
    env.update({"FIXSTREAM_SCENARIO": str(scenario), "FIXSTREAM_RATE": "0"})
    project = load_compose(REPO / "compose.yaml", environ=env, overrides={"FIXSTREAM_RECORDINGS": str(tmp_path)})
    plan = plan_stack(project, ["router", "recorder", "player"], environ=env)
    return {p.service: p for p in plan.processes}


class Processes:
    """Started processes, each stopped with SIGTERM (then SIGKILL) at the end, last started first."""

    def __init__(self) -> None:
        self.procs: dict[str, subprocess.Popen[str]] = {}

    def start(self, spec: ProcessSpec) -> subprocess.Popen[str]:
        proc = subprocess.Popen(
            spec.argv, env=spec.env, cwd=spec.cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self.procs[spec.service] = proc
        return proc

    def stop(self, name: str) -> tuple[str, str]:
        proc = self.procs.pop(name)
        proc.terminate()
        try:
            return proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            return proc.communicate()

    def close(self) -> None:
        for name in reversed(list(self.procs)):
            self.stop(name)


@pytest.fixture()
def processes() -> Iterator[Processes]:
    procs = Processes()
    try:
        yield procs
    finally:
        procs.close()


def start_router(procs: Processes, spec: ProcessSpec) -> None:
    procs.start(spec)
    assert spec.router_port is not None
    assert wait_until(lambda: port_open(spec.router_port or 0), timeout=30), "router did not listen"


def test_compose_player_waits_for_the_recorder_instance_compose_runs() -> None:
    project = load_compose(REPO / "compose.yaml", environ={})
    recorder = project.services["recorder"]
    command = project.services["player"].command
    assert command[command.index("--wait-for") + 1] == f"recorder/{recorder.environment['FIXSTREAM_RECORDER_INSTANCE']}"


@pytest.mark.e2e
def test_player_started_before_the_recorder_waits_and_everything_is_recorded(
    tmp_path: Path, processes: Processes
) -> None:
    specs = compose_processes(tmp_path, timeout_s=60)
    start_router(processes, specs["router"])
    player = processes.start(specs["player"])
    time.sleep(4.0)  # the player is up and connected long before the recorder exists
    assert player.poll() is None, player.communicate()
    assert not list(tmp_path.glob("*.mcap"))
    processes.start(specs["recorder"])
    _out, err = player.communicate(timeout=90)
    processes.procs.pop("player")
    assert player.returncode == 0, err
    processes.stop("recorder")

    files = sorted(tmp_path.glob("*.mcap"))
    assert len(files) == 1, (files, err)
    recorded: Counter[str] = Counter()
    end: ScenarioMarker | None = None
    for record in iter_records(files[0]):
        if record.topic == "fixstream/scenario/late_recorder":
            marker = decode_record(record)
            assert isinstance(marker, ScenarioMarker)
            end = marker if marker.event == "end" else end
        else:
            recorded[record.topic] += 1
    # the end marker carries what the player published per key: every one of them was recorded, none was
    # published into a network with no recorder on it
    assert end is not None, sorted(recorded)
    published = dict(end.published)
    assert sum(published.values()) > 100
    assert dict(recorded) == published


@pytest.mark.e2e
def test_player_that_never_sees_the_recorder_fails_with_one_line(tmp_path: Path, processes: Processes) -> None:
    specs = compose_processes(tmp_path, timeout_s=2)
    start_router(processes, specs["router"])
    player = processes.start(specs["player"])
    out, err = player.communicate(timeout=60)
    processes.procs.pop("player")
    assert player.returncode == 3, (out, err)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines == [
        "fixstream play: late_recorder: waiting for services: no live token on fixstream/alive/recorder/main after 2 s"
    ], err
    assert not list(tmp_path.glob("*.mcap"))
