"""The player over a real Zenoh router: every event in order, the end marker's counts, pacing, wait_for."""

from __future__ import annotations

import subprocess
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import fixstream_cmd, wait_until
from test_scenario_files import REPO, nav_scenario, write_scenario

from schemas import ScenarioMarker
from services.player.scenario import load_scenario
from services.player.timeline import scenario_events
from shared import codec, keys
from shared.session import open_session
from shared.settings import ZenohSettings

pytestmark = pytest.mark.e2e


class Collector:
    """A subscriber session on ``fixstream/**`` keeping (key, payload, encoding, arrival time)."""

    def __init__(self, endpoint: str) -> None:
        self.session = open_session(ZenohSettings(connect=[endpoint]))
        self.samples: list[tuple[str, bytes, str, float]] = []
        self._lock = threading.Lock()
        self.sub = self.session.declare_subscriber(keys.ALL, self._on)

    def _on(self, sample: object) -> None:
        item = (str(sample.key_expr), sample.payload.to_bytes(), str(sample.encoding), time.monotonic())  # type: ignore[attr-defined]
        with self._lock:
            self.samples.append(item)

    def markers(self) -> list[ScenarioMarker]:
        with self._lock:
            items = list(self.samples)
        out = []
        for key, payload, enc, _ in items:
            if key.startswith("fixstream/scenario/"):
                msg = codec.decode(payload, enc)
                assert isinstance(msg, ScenarioMarker)
                out.append(msg)
        return out

    def ended(self) -> bool:
        return any(m.event == "end" for m in self.markers())

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()


@pytest.fixture()
def collector(router: str) -> Iterator[Collector]:
    c = Collector(router)
    time.sleep(0.3)  # let the router learn the subscription
    yield c
    c.close()


def _play(endpoint: str, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        fixstream_cmd("play", *args, "--connect", endpoint, "--linger", "0.3"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )


def test_every_event_arrives_in_order_with_seq_and_the_end_marker_counts(
    router: str, collector: Collector, tmp_path: Path
) -> None:
    path = write_scenario(tmp_path, nav_scenario(name="full", duration_s=30.0))
    proc = _play(router, str(path), "--rate", "0", "--no-wait", "--instance", "t1", "--seed", "11")
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert wait_until(collector.ended, timeout=10)
    expected = scenario_events(load_scenario(path), 11, instance="t1")
    got = collector.samples
    assert got[0][0] == keys.scenario("full") and got[-1][0] == keys.scenario("full")
    data = got[1:-1]
    # the same messages, byte for byte, in the same (stamp) order
    assert [(k, p) for k, p, _, _ in data] == [(e.key, codec.encode(e.msg)) for e in expected]
    assert [enc for _, _, enc, _ in data] == [codec.encoding_of(type(e.msg)) for e in expected]
    seqs: dict[str, list[int]] = defaultdict(list)
    stamps = []
    for key, payload, enc, _ in data:
        msg = codec.decode(payload, enc)
        seqs[key].append(msg.header.seq)
        stamps.append(msg.header.stamp_ns)
        assert msg.header.source == "player/t1"
    assert stamps == sorted(stamps)
    for seq in seqs.values():
        assert seq == list(range(len(seq)))
    start, end = collector.markers()
    assert (start.event, end.event, start.seed, end.scenario) == ("start", "end", 11, "full")
    assert end.published == dict(Counter(k for k, _, _, _ in data))
    assert sum(end.published.values()) == len(expected) > 1000
    assert f"published {len(expected)} messages" in out


def test_rate_paces_by_the_data_stamps(router: str, collector: Collector, tmp_path: Path) -> None:
    doc = nav_scenario(name="paced", duration_s=2.0, sensors=[])
    path = write_scenario(tmp_path, doc)
    proc = _play(router, str(path), "--rate", "10", "--no-wait")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert wait_until(collector.ended, timeout=10)
    arrivals = [t for k, _, _, t in collector.samples if k == keys.truth("auv1")]
    assert len(arrivals) == 21
    span = arrivals[-1] - arrivals[0]  # 2 s of data at 10x real time: 0.2 s
    assert 0.15 <= span <= 5.0, span
    # the first half of the data arrives in roughly the first half of the span
    assert arrivals[10] - arrivals[0] >= 0.05  # half of the 0.1 s it should take: paced, not flushed at once


def _token_scenario(tmp_path: Path, name: str, timeout_s: float) -> Path:
    doc = nav_scenario(name=name, duration_s=1.0, sensors=[])
    doc["wait_for"] = ["estimator_x/inst1", "estimator_y"]
    doc["wait_timeout_s"] = timeout_s
    return write_scenario(tmp_path, doc)


def test_wait_for_blocks_until_every_token_is_alive(router: str, collector: Collector, tmp_path: Path) -> None:
    path = _token_scenario(tmp_path, "waiting", 30.0)
    proc = _play(router, str(path), "--rate", "0")
    tokens = []
    try:
        time.sleep(1.5)
        assert proc.poll() is None and collector.samples == []
        tokens.append(collector.session.liveliness().declare_token(keys.alive("estimator_x", "inst1")))
        time.sleep(1.0)
        assert proc.poll() is None and collector.samples == []  # estimator_y (any instance) still missing
        tokens.append(collector.session.liveliness().declare_token(keys.alive("estimator_y", "whatever")))
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 0, err
        assert wait_until(collector.ended, timeout=10)
        assert [m.event for m in collector.markers()] == ["start", "end"]
    finally:
        for t in tokens:
            t.undeclare()
        if proc.poll() is None:
            proc.kill()


def test_wait_for_times_out_with_a_clear_error_and_publishes_nothing(
    router: str, collector: Collector, tmp_path: Path
) -> None:
    path = _token_scenario(tmp_path, "lonely", 1.0)
    token = collector.session.liveliness().declare_token(keys.alive("estimator_x", "inst1"))
    try:
        proc = _play(router, str(path), "--rate", "0")
        _, err = proc.communicate(timeout=30)
    finally:
        token.undeclare()
    assert proc.returncode == 3
    assert "fixstream/alive/estimator_y/*" in err and "estimator_x" not in err.split("no live token on")[-1]
    time.sleep(0.3)
    assert collector.samples == []
