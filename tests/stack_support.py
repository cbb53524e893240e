"""What the end-to-end tests of every estimator share: run the stack, read the recording, build the offline twin.

The pattern (architecture rule 1): a scenario goes through ``fixstream up router recorder player <services>``
(the repository's compose.yaml, rate 0); what the recorder wrote must equal, message for message and header
included, what the same service, built as ``build()`` builds it from the compose file's environment, gives from
``run_offline`` on the scenario's events framed by the player's start and end markers.
"""

from __future__ import annotations

import os
import subprocess
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TypeVar

import pytest
import zenoh
from conftest import REPO, fixstream_cmd

from schemas import Message
from services.player.scenario import Scenario
from services.player.timeline import marker, scenario_events
from shared import keys
from shared.mcap_io import decode_record, iter_records, recording_files
from shared.service import Output, Service
from shared.stack import load_compose

COMPOSE = REPO / "compose.yaml"

Feed = list[tuple[str, Message]]
S = TypeVar("S", bound=Service)


def scenario_feed(scenario: Scenario, seed: int | None = None) -> Feed:
    """Exactly what ``fixstream play`` publishes for the scenario, as (key, message)."""
    return [(ev.key, ev.msg) for ev in scenario_events(scenario, seed)]


def framed(scenario: Scenario, feed: Feed, seed: int | None = None) -> Feed:
    """The feed between the player's start and end markers (the end marker counts the messages per key)."""
    seed = scenario.seed if seed is None else seed
    key = keys.scenario(scenario.name)
    last = max((m.header.stamp_ns for _, m in feed), default=0)
    counts = Counter(k for k, _ in feed)
    return [
        (key, marker(scenario, seed, "start", 0, 0)),
        *feed,
        (key, marker(scenario, seed, "end", last, 1, published=dict(counts))),
    ]


def delivered(svc: Service, feed: Iterable[tuple[str, Message]]) -> Feed:
    """The part of a feed the service's subscriptions (and the base's scenario subscription) receive."""
    exprs = [zenoh.KeyExpr(s.key_expr) for s in svc.subscriptions()] + [zenoh.KeyExpr(f"{keys.ROOT}/scenario/**")]
    return [(k, m) for k, m in feed if any(ke.intersects(zenoh.KeyExpr(k)) for ke in exprs)]


def on_key(outputs: Sequence[Output], key: str) -> list[Message]:
    return [o.msg for o in outputs if o.key == key]


def stack_env(scenario: Path) -> dict[str, str]:
    """This process's environment without FIXSTREAM_* settings, plus the scenario at rate 0."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_")}
    env.update({"FIXSTREAM_SCENARIO": str(scenario), "FIXSTREAM_RATE": "0"})
    return env


def run_up(tmp_path: Path, scenario: Path, services: Sequence[str], timeout_s: float = 180) -> tuple[str, Path]:
    """``fixstream up router recorder player <services>`` on the scenario; returns (log, recordings dir).

    Fails unless the stack exits cleanly and every named service reported ready (liveliness seen).
    """
    recordings = tmp_path / "recordings"
    cmd = ["up", "-f", str(COMPOSE), "router", "recorder", "player", *services, "--recordings", str(recordings)]
    done = subprocess.run(
        fixstream_cmd(*cmd, "--no-color"),
        cwd=tmp_path,
        env=stack_env(scenario),
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )
    log = done.stdout + done.stderr
    assert done.returncode == 0, log[-5000:]
    for service in services:
        assert f"[up] {service} ready: " in log, (service, log[-3000:])
    return log, recordings


def player_waited_for(log: str, alive_key: str) -> bool:
    """The player saw the service's liveliness token (its scenario's wait_for) before publishing."""
    return any("fixstream.player: alive:" in line and alive_key in line for line in log.splitlines())


def recorded_by_topic(recordings: Path) -> dict[str, list[Message]]:
    """Every message of every MCAP file in the directory, per topic (= key), in file order."""
    files = recording_files(recordings)
    assert files, f"no MCAP in {recordings}"
    by_topic: dict[str, list[Message]] = {}
    for f in files:
        for rec in iter_records(f):
            by_topic.setdefault(rec.topic, []).append(decode_record(rec))
    return by_topic


def as_composed(monkeypatch: pytest.MonkeyPatch, service: str, build: Callable[[], S], scenario: Path) -> S:
    """The service built as ``build()`` builds it in the stack: from the compose file's (interpolated)
    environment of that compose service, and nothing else of this process's FIXSTREAM_* settings."""
    for name in [k for k in os.environ if k.startswith("FIXSTREAM_")]:
        monkeypatch.delenv(name)
    for name, value in load_compose(COMPOSE, environ=stack_env(scenario)).services[service].environment.items():
        monkeypatch.setenv(name, value)
    return build()
