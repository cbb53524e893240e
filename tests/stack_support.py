"""What the end-to-end tests of every estimator share: run the stack, read the recording, build the offline twin.

The pattern (architecture rule 1): a scenario goes through ``fixstream up router recorder player <services>``
(the repository's compose.yaml, rate 0); what the recorder wrote must equal, message for message and header
included, what the same service, built as ``build()`` builds it from the compose file's environment, gives from
``run_offline`` on the scenario's events framed by the player's start and end markers.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import threading
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import pytest
import zenoh
from conftest import REPO, fixstream_cmd, service_env, wait_until

from schemas import Diagnostic, Message, ScenarioMarker
from services.player.scenario import Scenario
from services.player.timeline import marker, scenario_events
from shared import codec, keys
from shared.mcap_io import REJECTED_PREFIX, decode_record, iter_records, recording_files
from shared.service import Output, Service
from shared.session import open_session
from shared.settings import ZenohSettings
from tools.stack import load_compose

COMPOSE = REPO / "compose.yaml"

Feed = list[tuple[str, Message]]
#: a sample as it travels: (key, payload, encoding)
Raw = tuple[str, bytes, str]
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


def without_source_seq(msgs: Iterable[Message]) -> list[Message]:
    """The messages with the header's seq and source blanked (what a core in-process does not set)."""
    return [m.model_copy(update={"header": m.header.model_copy(update={"seq": 0, "source": ""})}) for m in msgs]


def counters_add_up(svc: Service) -> None:
    c = svc.counters
    assert c.received == c.accepted + c.rejected
    assert c.rejected == sum(c.rejected_by_reason.values())


def raw(key: str, msg: Message) -> Raw:
    """The message as the player puts it on the wire."""
    return key, codec.encode(msg), codec.encoding_of(type(msg))


def announced(items: Iterable[Raw], source: str) -> Counter[str]:
    """Per data key, the items a player publishing as ``source`` announces in its end marker: those whose header
    names ``source``, a repeat of its last seq on the key aside (the service base counts exactly these)."""
    published: Counter[str] = Counter()
    last_seq: dict[str, int] = {}
    for key, payload, _ in items:
        header = codec.peek_header(payload)
        if key.startswith(f"{keys.ROOT}/scenario/") or header is None or header[0] != source:
            continue  # a marker, nobody's payload, or another publisher's
        if last_seq.get(key) == header[1]:
            continue  # a repeat of the player's last message on the key
        last_seq[key] = header[1]
        published[key] += 1
    return published


def with_end_marker(scenario: Scenario, items: list[Raw], last_stamp_ns: int) -> list[Raw]:
    """The items and, last, the player's end marker counting per key the items that are the player's: those whose
    header names the player's source (the service base counts only these; a payload that does not even unpack, or
    comes from another source, is nobody's and cannot end or extend the player's run)."""
    published = announced(items, marker(scenario, scenario.seed, "end", 0, 1).header.source)
    end = marker(scenario, scenario.seed, "end", last_stamp_ns, 1, published=dict(published))
    return [*items, (keys.scenario(scenario.name), codec.encode(end), codec.encoding_of(ScenarioMarker))]


def offline_on_bytes(twin: Service, items: Iterable[Raw]) -> list[Output]:
    """The service fed exactly these bytes, as the Zenoh callback path feeds them; returns what it published."""
    twin.run_offline([])  # declares the subscriptions
    start = len(twin.outbox)
    for key, payload, encoding in items:
        twin.process(key, payload, encoding, rx_time_ns=0)
    return twin.outbox[start:]


def stack_env(scenario: Path) -> dict[str, str]:
    """This process's environment without FIXSTREAM_* settings, plus the scenario at rate 0."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_") or k == "FIXSTREAM_STATE_DIR"}
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
            if rec.topic.startswith(REJECTED_PREFIX):
                continue  # payloads that failed validation, kept as raw bytes (not messages)
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


@contextlib.contextmanager
def composed_env(service: str, scenario: Path | None = None) -> Iterator[None]:
    """This process's environment as compose gives it to ``service`` (no other FIXSTREAM_* setting), and the
    repository as the working directory, for the duration of the block."""
    saved, cwd = dict(os.environ), Path.cwd()
    environ = stack_env(scenario) if scenario is not None else {"PATH": os.environ.get("PATH", "")}
    spec = load_compose(COMPOSE, environ=environ).services[service]
    os.environ.clear()
    os.environ.update({k: v for k, v in saved.items() if not k.startswith("FIXSTREAM_") or k == "FIXSTREAM_STATE_DIR"})
    os.environ.update({k: v for k, v in spec.environment.items() if v is not None})
    os.chdir(REPO)
    try:
        yield
    finally:
        os.environ.clear()
        os.environ.update(saved)
        os.chdir(cwd)


def build_composed(service: str, name: str) -> Service:
    """``services.<name>.service.build()`` as the compose service ``service`` builds it."""
    import importlib

    with composed_env(service):
        built: Service = importlib.import_module(f"services.{name}.service").build()  # type: ignore[attr-defined]
    return built


# --- one service process on a real router (the bad-input tests) ---------------------------------------------------


class LiveService:
    """A ``fixstream run <name>`` process on a router, and a client session that collects what it publishes."""

    def __init__(self, router: str, name: str, instance: str, listen: Sequence[str], env: dict[str, str]) -> None:
        self.name, self.instance = name, instance
        self.diag_key = keys.diag(name, instance)
        self.received: dict[str, list[Message]] = defaultdict(list)
        self._lock = threading.Lock()
        self._pubs: dict[str, zenoh.Publisher] = {}
        self.proc = subprocess.Popen(
            fixstream_cmd("run", name),
            env=service_env(router, **env),
            cwd=REPO,
            text=True,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        self.client = open_session(ZenohSettings(mode="client", connect=[router]))
        self._subs = [self.client.declare_subscriber(k, self._keep) for k in (*listen, self.diag_key)]
        self.output = ""

    def _keep(self, sample: zenoh.Sample) -> None:
        msg = codec.decode(sample.payload.to_bytes(), str(sample.encoding))
        with self._lock:
            self.received[str(sample.key_expr)].append(msg)

    def count(self, key: str) -> int:
        with self._lock:
            return len(self.received[key])

    def alive(self, timeout_s: float = 0.5) -> bool:
        return len(list(self.client.liveliness().get(keys.alive(self.name, self.instance), timeout=timeout_s))) == 1

    def put_raw(self, items: Iterable[tuple[str, bytes, str]]) -> None:
        """Publish raw (key, payload, encoding) items in order, one blocking publisher per key."""
        for key, payload, encoding in items:
            pub = self._pubs.get(key)
            if pub is None:
                pub = self._pubs[key] = self.client.declare_publisher(
                    key, congestion_control=zenoh.CongestionControl.BLOCK
                )
            pub.put(payload, encoding=zenoh.Encoding(encoding))

    def status(self) -> dict[str, Any]:
        replies = list(self.client.get(keys.status(self.name, self.instance), timeout=5.0))
        assert len(replies) == 1 and replies[0].ok is not None, replies
        return dict(json.loads(replies[0].ok.payload.to_bytes()))

    def wait_status(self, settled: Callable[[dict[str, Any]], bool], timeout_s: float = 30) -> dict[str, Any]:
        """The first status for which ``settled`` holds (fails after ``timeout_s``)."""
        seen: dict[str, Any] = {}

        def check() -> bool:
            seen.clear()
            seen.update(self.status())
            return settled(seen)

        assert wait_until(check, timeout=timeout_s), seen
        return seen

    def close(self) -> int:
        """SIGTERM the service (it drains and exits 0), close the client; the process output is in ``output``."""
        for s in self._subs:
            with contextlib.suppress(Exception):
                s.undeclare()
        with contextlib.suppress(Exception):
            self.client.close()
        self.proc.terminate()
        self.output, _ = self.proc.communicate(timeout=30)
        return self.proc.returncode


@contextlib.contextmanager
def live_service(
    router: str, name: str, instance: str, listen: Sequence[str] = (), **env: str
) -> Iterator[LiveService]:
    """``fixstream run <name>`` with ``env`` (its instance in ``FIXSTREAM_<NAME>_INSTANCE``), up and alive;
    a client subscribed to ``listen`` and the service's diag key. On leaving, the service must exit cleanly
    (code 0 after SIGTERM, no traceback, no internal error)."""
    env = {f"FIXSTREAM_{name.upper()}_INSTANCE": instance, **env}
    live = LiveService(router, name, instance, listen, env)
    try:
        assert wait_until(live.alive, timeout=60), f"{name}/{instance} did not come up"
        yield live
    finally:
        code = live.close()
    assert code == 0, live.output[-3000:]
    assert "internal_error" not in live.output and "Traceback" not in live.output, live.output[-3000:]


@dataclass
class LiveRun:
    """What a live service published for a bad-input run, and its status once the run had ended."""

    status: dict[str, Any]
    received: dict[str, list[Message]]
    diags: list[Diagnostic]


def live_run_equals_offline(
    router: str,
    name: str,
    instance: str,
    listen: Sequence[str],
    items: Sequence[Raw],
    offline: Sequence[Output],
    expected: Counter[str],
    **env: str,
) -> LiveRun:
    """``items`` on the wire to ``fixstream run <name>`` (see :func:`live_service`): it publishes on every key as
    many messages as its offline twin (``offline``, on the same bytes), stays alive, ends the run (two sessions),
    and its counters add up to exactly the ``expected`` refusals; once it is stopped, its outputs equal the twin's
    message for message and its diagnostics give the twin's reasons."""
    n_out = Counter(o.key for o in offline)
    with live_service(router, name, instance, listen, **env) as live:
        live.put_raw(items)
        assert wait_until(lambda: all(live.count(k) == n for k, n in n_out.items()), timeout=60), {
            k: (live.count(k), n) for k, n in n_out.items()
        }
        assert live.proc.poll() is None and live.alive(1.0)  # still alive, and its status adds up
        status = live.wait_status(lambda st: st["sessions"] == 2, timeout_s=20)
        c = status["counters"]
        assert c["received"] == len(items) == c["accepted"] + c["rejected"]
        assert c["rejected_by_reason"] == dict(expected) and c["rejected"] == sum(expected.values())
    received = live.received
    for k in n_out:
        assert received[k] == on_key(offline, k), k
    diags = [d for d in received[live.diag_key] if isinstance(d, Diagnostic)]
    off_diags = [m for m in (o.msg for o in offline) if isinstance(m, Diagnostic)]
    assert Counter(d.reason for d in diags) == Counter(d.reason for d in off_diags)
    return LiveRun(status, received, diags)
