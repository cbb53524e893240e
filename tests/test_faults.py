"""Faults over real processes: a fuzz campaign against the whole estimator stack, and a service too busy to keep up.

The campaign (issue 14's acceptance, small-N here; ``FIXSTREAM_FUZZ_N=20000 pytest tests/test_faults.py -k campaign``
runs the full 20,000 payloads per service):
every estimator of compose.yaml runs under ``fixstream up`` behind one router; one client puts hostile payloads
(tests/hostile_payloads.py) on each service's input keys inside a player run of its own; then the real player
plays the demo scenario to the recorder. Every service must still be alive, its counters must equal what was sent
to it, its memory must stay bounded, and its fixes for the demo run must equal, message for message, those of a
fresh offline twin on the same scenario: nothing of the junk reached the next run.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
import zenoh
from conftest import REPO, fixstream_cmd, wait_until
from hostile_payloads import hostile_items
from stack_support import (
    build_composed,
    delivered,
    framed,
    recorded_by_topic,
    scenario_feed,
    stack_env,
    without_source_seq,
)

from schemas import Depth, Diagnostic, Header, ScenarioMarker
from schemas.pcl_tracker import PclScanReport
from services.player.scenario import load_scenario
from shared import codec, keys
from shared.session import open_session, query_all
from shared.settings import ZenohSettings

pytestmark = pytest.mark.e2e

#: compose service -> estimator service name
ESTIMATORS = {
    "terrain_nav-tan1": "terrain_nav",
    "pcl_tracker-rx1-fm": "pcl_tracker",
    "pcl_tracker-rx1-dvbt": "pcl_tracker",
    "attitude-r1": "attitude",
    "lbl_nav-lbl1": "lbl_nav",
    "coordinator-group1": "coordinator",
    "rd_nav-auv3": "rd_nav",
    "rd_nav-auv4": "rd_nav",
}
FUZZ_N = int(os.environ.get("FIXSTREAM_FUZZ_N", "150"))
#: resident memory a service may reach after the campaign (each starts at 100-200 MB with numpy and zenoh)
RSS_BOUND_MB = 600


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


class _Stack:
    """``fixstream up`` of the given compose services (router included), in the background."""

    def __init__(self, tmp: Path, services: list[str], scenario: Path) -> None:
        self.proc = subprocess.Popen(
            fixstream_cmd("up", "-f", str(REPO / "compose.yaml"), "router", *services, "--router-port", "0"),
            cwd=tmp,
            env={**stack_env(scenario), "FIXSTREAM_LOG_LEVEL": "WARNING"},
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()
        assert wait_until(lambda: all(any(f"{s} ready" in ln for ln in self.lines) for s in services), timeout=120), (
            self.lines[-30:]
        )
        line = next(ln for ln in self.lines if "router on tcp/" in ln)
        self.endpoint = line.split("router on ")[1].split(";")[0]

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def pids(self) -> dict[str, int]:
        """compose service -> pid, from the runner's children (``fixstream run <name>`` with its instance)."""
        out: dict[str, int] = {}
        children = Path(f"/proc/{self.proc.pid}/task/{self.proc.pid}/children").read_text().split()
        for pid in map(int, children):
            try:
                environ = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
            except OSError:
                continue
            env = dict(e.decode(errors="replace").split("=", 1) for e in environ if b"=" in e)
            for compose_name, name in ESTIMATORS.items():
                if env.get(f"FIXSTREAM_{name.upper()}_INSTANCE") == compose_name.split("-", 1)[1]:
                    out[compose_name] = pid
        return out

    def stop(self) -> int:
        self.proc.send_signal(signal.SIGINT)
        return self.proc.wait(timeout=120)


def _statuses(session: zenoh.Session) -> dict[tuple[str, str], dict[str, Any]]:
    out = {}
    for reply in query_all(session, "fixstream/status/**", 5.0):
        if reply.ok is not None:
            body = json.loads(reply.ok.payload.to_bytes())
            out[(body["service"], body["instance"])] = body
    return out


def _canonical(msgs: list[Any]) -> list[Any]:
    """PCL track ids renumbered by first appearance: a tracker never reuses an id within its life (digest 003), so
    the tracks the junk run started move the next run's ids on; everything else must be equal."""
    ids: dict[int, int] = {}
    out = []
    for m in msgs:
        if isinstance(m, PclScanReport):
            tracks = [t.model_copy(update={"track_id": ids.setdefault(t.track_id, len(ids) + 1)}) for t in m.tracks]
            m = m.model_copy(update={"tracks": tracks})
        out.append(m)
    return out


def _marker(event: str, seq: int) -> tuple[str, bytes, str]:
    header = Header(stamp_ns=0, source="player/fuzz", seq=seq)
    m = ScenarioMarker(header=header, event="start" if event == "start" else "end", scenario="fuzz", seed=0)
    return keys.scenario("fuzz"), codec.encode(m), codec.encoding_of(ScenarioMarker)


def test_a_fuzz_campaign_leaves_every_service_alive_counted_bounded_and_its_next_run_clean(tmp_path: Path) -> None:
    scenario = REPO / "scenarios" / "demo.yaml"
    sc = load_scenario(scenario)
    feed = scenario_feed(sc)
    twins = {c: build_composed(c, name) for c, name in ESTIMATORS.items()}
    stack = _Stack(tmp_path, list(ESTIMATORS), scenario)
    client = open_session(ZenohSettings(mode="client", connect=[stack.endpoint]))
    try:
        # the junk: per service, hostile payloads on its own input keys, inside one run of the fuzzing "player"
        items = [_marker("start", 0)]
        for i, twin in enumerate(twins.values()):
            inputs = [(k, m) for k, m in delivered(twin, feed) if not isinstance(m, ScenarioMarker)]
            items += hostile_items(inputs, FUZZ_N, seed=1000 + i)
        pubs: dict[str, zenoh.Publisher] = {}

        def put(batch: list[tuple[str, bytes, str]]) -> None:
            for key, payload, encoding in batch:
                pub = pubs.get(key) or pubs.setdefault(
                    key, client.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
                )
                pub.put(payload, encoding=zenoh.Encoding(encoding) if encoding else None)

        status: dict[tuple[str, str], dict[str, Any]] = {}

        def settled(batch: list[tuple[str, bytes, str]]) -> bool:
            """Every service received (or dropped, counted) every item of ``batch`` on its keys."""
            sent = {c: len(delivered(t, [(k, None) for k, _, _ in batch])) for c, t in twins.items()}  # type: ignore[misc]
            status.clear()
            status.update(_statuses(client))
            return all(
                (st := status.get((ESTIMATORS[c], c.split("-", 1)[1]))) is not None
                and st["counters"]["received"] + st["counters"]["dropped"] == sent[c]
                for c in ESTIMATORS
            )

        # the junk run ends once its junk is in: an end marker overtaking junk on other keys would let the late
        # junk into the next run, as junk from a foreign source arriving during any run would (what the ACL of
        # the secure stack stops)
        put(items)
        assert wait_until(lambda: settled(items), timeout=120), {k: v["counters"] for k, v in status.items()}
        items.append(_marker("end", 1))
        put(items[-1:])
        assert wait_until(lambda: settled(items), timeout=60), {k: v["counters"] for k, v in status.items()}
        for c, pid in stack.pids().items():
            st = status[(ESTIMATORS[c], c.split("-", 1)[1])]
            cnt = st["counters"]
            assert cnt["received"] == cnt["accepted"] + cnt["rejected"], (c, cnt)
            assert cnt["publish_failed"] == 0 and "internal_error" not in cnt["rejected_by_reason"], (c, cnt)
            assert st["scenario"]["end_pending"] is False
            assert _rss_mb(pid) < RSS_BOUND_MB, (c, _rss_mb(pid))
        # the next run: the real player plays the demo to a recorder
        recordings = tmp_path / "rec"
        env = {**stack_env(scenario), "FIXSTREAM_ZENOH_CONNECT": stack.endpoint, "FIXSTREAM_LOG_LEVEL": "WARNING"}
        recorder = subprocess.Popen(
            fixstream_cmd("record", "--out-dir", str(recordings), "--instance", "fuzz"), cwd=REPO, env=env
        )
        try:
            done = subprocess.run(
                fixstream_cmd("play", str(scenario), "--rate", "0"),
                cwd=REPO,
                env=env,
                capture_output=True,
                text=True,
                timeout=300,
            )
            assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
            ends = {c: 2 for c in ESTIMATORS}  # the fuzz run and the demo run

            def ended() -> bool:
                st = _statuses(client)
                return all(
                    sum(st[(ESTIMATORS[c], c.split("-", 1)[1])]["scenario"]["ends"].values()) >= n
                    for c, n in ends.items()
                )

            assert wait_until(ended, timeout=120)
            time.sleep(1.0)  # the last outputs reach the recorder
        finally:
            recorder.terminate()
            assert recorder.wait(timeout=60) == 0
        recorded = recorded_by_topic(recordings)
        for compose_name, twin in twins.items():
            offline = twin.run_offline(framed(sc, delivered(twin, feed)))
            by_key: dict[str, list[Any]] = {}
            for o in offline:
                if not isinstance(o.msg, Diagnostic):
                    by_key.setdefault(o.key, []).append(o.msg)
            assert by_key, compose_name
            for key, msgs in by_key.items():
                live = [m for m in recorded.get(key, []) if not isinstance(m, Diagnostic)]
                got, want = _canonical(without_source_seq(live)), _canonical(without_source_seq(msgs))
                assert got == want, (
                    compose_name,
                    key,
                    [m.header.stamp_ns for m in live],
                    [m.header.stamp_ns for m in msgs],
                )
    finally:
        client.close()
        rc = stack.stop()
    assert rc in (0, 130), stack.lines[-30:]
    assert not any("Traceback" in ln for ln in stack.lines), "\n".join(ln for ln in stack.lines if "Error" in ln)


# --- a service too busy to keep up ----------------------------------------------------------------------------------

SLOW_SERVICE = """
import sys, time
from shared.service import Service, Subscription
from shared.settings import ServiceSettings
from schemas import Depth


class Slow(Service):
    name = "slow_test"

    def __init__(self, settings):
        super().__init__(settings)
        self.first = True

    def subscriptions(self):
        return [Subscription("fixstream/sensor/slow/**", self.on_depth, accepts=(Depth,))]

    def on_depth(self, key, msg):
        if self.first:  # one step that takes 8 s: longer than the 5 s that used to cost the session
            self.first = False
            time.sleep(8.0)
        return []


svc = Slow(ServiceSettings.load(instance="busy", queue_size=200, enqueue_block_s=0.5))
svc.install_signal_handlers()
sys.exit(svc.run())
"""


def test_a_busy_service_keeps_its_session_and_counts_every_sample_it_drops(router: str, tmp_path: Path) -> None:
    script = tmp_path / "slow.py"
    script.write_text(SLOW_SERVICE)
    env = {**os.environ, "FIXSTREAM_ZENOH_MODE": "client", "FIXSTREAM_ZENOH_CONNECT": router}
    proc = subprocess.Popen([sys.executable, str(script)], cwd=REPO, env=env, text=True, stderr=subprocess.PIPE)
    client = open_session(ZenohSettings(mode="client", connect=[router]))
    tokens: Counter[str] = Counter()
    watch = client.liveliness().declare_subscriber(
        keys.alive("slow_test", "busy"), lambda s: tokens.update([str(s.kind)]), history=True
    )
    try:
        assert wait_until(lambda: tokens["SampleKind.PUT"] == 1, timeout=60)
        pub = client.declare_publisher(
            "fixstream/sensor/slow/depth/d", congestion_control=zenoh.CongestionControl.BLOCK
        )
        enc = zenoh.Encoding(codec.encoding_of(Depth))
        n = 3000
        for i in range(n):
            msg = Depth(header=Header(stamp_ns=i), depth_m=1.0)
            pub.put(codec.encode_stamped(msg, "player/busy", i), encoding=enc)
            if i % 100 == 0:
                time.sleep(0.05)  # 12 s of publishing at ~2,000 msg/s, across the 8 s stall
        status: dict[str, Any] = {}

        def accounted() -> bool:
            replies = query_all(client, keys.status("slow_test", "busy"), 2.0)
            if not replies or replies[0].ok is None:
                return False
            status.update(json.loads(replies[0].ok.payload.to_bytes()))
            c = status["counters"]
            return bool(c["received"] + c["dropped"] == n)

        assert wait_until(accounted, timeout=60), status.get("counters")
        assert status["counters"]["dropped"] > 0  # the stall overflowed the 200-sample queue
        assert tokens["SampleKind.DELETE"] == 0, "the session was dropped while the service was busy"
        assert status["seq"]["lost"] == 0  # nothing vanished in transport: the drops are the service's, counted
    finally:
        watch.undeclare()
        client.close()
        proc.terminate()
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err[-3000:]
