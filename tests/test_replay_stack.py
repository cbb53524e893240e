"""Issue 17's acceptance over real processes: a recording made with bad inputs, replayed into a second stack, gives
every service the same status counters (rejections by reason included) and the same fixes and tracks, message for
message.

Stack: a router, the demo's terrain navigation (tan1: its NaN radio-altimeter samples) and PCL tracker (rx1-fm)
services as compose.yaml configures them, and a recorder; the demo scenario cut to those two parts (the other
estimators' parts would only add services and minutes, not another path through the recorder or the replay). Beside
the demo's own NaN samples the test publishes schema-invalid and undecodable payloads on the services' input keys
(from a client of its own, before the player's start marker and after its end marker), which the recorder keeps on
``fixstream/rejected/<key>``. Stack B is a fresh router, fresh services and a fresh recorder; ``fixstream play FILE``
replays stack A's recording into it (the default selection: the player's keys, the rejected payloads on theirs, not
the recorded outputs).
"""

from __future__ import annotations

import contextlib
import json
import math
import subprocess
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import pytest
import yaml
from conftest import REPO, fixstream_cmd, running_router, service_env, wait_until
from recorder_support import Recorder, recorder
from stack_support import COMPOSE, LiveService, Raw, live_service, stack_env

from schemas import Message
from schemas.base import MAX_STAMP_NS
from services.player.scenario import load_scenario
from services.player.timeline import scenario_events
from shared import codec, keys
from shared.mcap_io import REJECTED_PREFIX, decode_rejected, iter_records, recording_files
from tools.stack import load_compose

pytestmark = pytest.mark.e2e

DEMO = REPO / "scenarios" / "demo.yaml"
#: (service, instance, compose service, output keys compared message for message)
SERVICES = (
    ("terrain_nav", "tan1", "terrain_nav-tan1", (keys.fix("terrain", "tan1"), keys.fix("terrain", "tan1", "verdict"))),
    ("pcl_tracker", "rx1-fm", "pcl_tracker-rx1-fm", (keys.track("pcl", "rx1", "tx-fm-98.1"),)),
)
#: status fields that depend on the wall clock or the process, not on the input (the PCL tracker's scan timings)
VOLATILE = ("uptime_s", "queue_depth", "queue_bytes", "last_scan_ms", "max_scan_ms", "mean_scan_ms", "mean_scan_cpu_ms")
#: the source of the test's own bad payloads (not a player: they count for no run)
JUNK_SOURCE = "fuzz/replay"


def demo_part(tmp_path: Path) -> Path:
    """The demo with only the terrain navigation and the FM PCL parts (simulators and estimators)."""
    doc = yaml.safe_load(DEMO.read_text())
    doc["simulators"] = [s for s in doc["simulators"] if s["id"] in ("tan1", "pcl_demo_fm")]
    doc["estimators"] = [e for e in doc["estimators"] if e["instance"] in ("tan1", "rx1-fm")]
    doc["wait_for"] = []  # the test names the services with --wait-for
    path = tmp_path / "scenarios" / "demo_part.yaml"
    path.parent.mkdir()
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def bad_payloads(inputs: dict[str, Message]) -> list[Raw]:
    """Per input key, one payload of each kind the services and the recorder must refuse (none of them a player's
    message: they count for no run)."""
    out: list[Raw] = []
    for i, (key, msg) in enumerate(sorted(inputs.items())):
        enc = codec.encoding_of(type(msg))
        good = codec.encode_stamped(msg, JUNK_SOURCE, 10 * i)
        obj: dict[str, Any] = codec.unpack(good)
        field = next(k for k in obj if k != "header")
        out += [
            (key, b"\xc1 not msgpack", enc),  # undecodable
            (key, good[: len(good) // 2], enc),  # truncated
            (key, msgpack.packb({k: v for k, v in obj.items() if k != field}), enc),  # a required field missing
            (key, msgpack.packb({**obj, field: "not this"}), enc),  # a field of the wrong type
            (key, msgpack.packb(_nan_floats(obj)), enc),  # NaN wherever there is a float
            (key, msgpack.packb({**obj, "header": {**obj["header"], "stamp_ns": MAX_STAMP_NS + 1}}), enc),
            (key, good, "application/msgpack;fixstream.NoSuchModel/1"),  # an unknown schema
            (key, good, "application/json"),  # not the wire encoding
        ]
    return out


def _nan_floats(obj: Any) -> Any:
    if isinstance(obj, float):
        return math.nan
    if isinstance(obj, dict):
        return {k: _nan_floats(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_nan_floats(v) for v in obj]
    return obj


def service_settings(compose_service: str, scenario: Path) -> dict[str, str]:
    """The compose service's environment (interpolated as ``fixstream up`` does), without its Zenoh endpoint."""
    env = load_compose(COMPOSE, environ=stack_env(scenario)).services[compose_service].environment
    return {k: v for k, v in env.items() if v is not None and not k.startswith("FIXSTREAM_ZENOH_")}


@contextlib.contextmanager
def stack(router: str, tmp_path: Path, scenario: Path, name: str) -> Iterator[tuple[Recorder, list[LiveService]]]:
    """A recorder and the services, each alive, on ``router``."""
    env = {"FIXSTREAM_RECORDER_SCENARIOS_DIR": str(scenario.parent)}
    (tmp_path / name).mkdir()
    with contextlib.ExitStack() as es:
        rec = es.enter_context(recorder(router, tmp_path / name, instance=name, **env))
        live = [
            es.enter_context(live_service(router, svc, inst, outs, **service_settings(compose_svc, scenario)))
            for svc, inst, compose_svc, outs in SERVICES
        ]
        yield rec, live
        rec.terminate()


def settled(status: Any, timeout_s: float = 60) -> dict[str, Any]:
    """Poll ``status()`` until two answers 1 s apart have the same counters; returns the last answer."""
    last: dict[str, Any] = {}

    def same() -> bool:
        nonlocal last
        before = status()
        time.sleep(1.0)
        last = status()
        return bool(before) and before["counters"] == last["counters"]

    assert wait_until(same, timeout=timeout_s, interval=0.1), last
    return last


def comparable(status: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in status.items() if k not in VOLATILE}


def play(router: str, target: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    waits = [a for svc, inst, _, _ in SERVICES for a in ("--wait-for", f"{svc}/{inst}")]
    done = subprocess.run(
        fixstream_cmd("play", str(target), "--rate", "0", *waits, *extra),
        env=service_env(router),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return done


def run_stack(tmp_path: Path, scenario: Path, name: str, target: Path, junk: list[Raw]) -> dict[str, Any]:
    """A fresh stack; ``junk`` published before and after ``fixstream play target``; every service's settled status
    and what it published on its output keys; the recording."""
    half = len(junk) // 2
    with running_router() as router, stack(router, tmp_path, scenario, name) as (rec, live):
        live[0].put_raw(junk[:half])
        played = play(router, target, "--wait-for", f"recorder/{name}")
        # the run ends: complete once every message the end marker announces has arrived, else incomplete after
        # the service's end_wait_s
        assert wait_until(lambda: all(sum(s.status()["scenario"]["ends"].values()) == 1 for s in live), 60), [
            s.status()["scenario"] for s in live
        ]
        live[0].put_raw(junk[half:])
        statuses = {f"{s.name}/{s.instance}": settled(s.status) for s in live}
        statuses[f"recorder/{name}"] = settled(rec.status)
    outputs = {key: list(s.received[key]) for s, (_, _, _, outs) in zip(live, SERVICES, strict=True) for key in outs}
    (path,) = recording_files(rec.out_dir)
    return {"status": statuses, "outputs": outputs, "file": path, "played": played.stdout}


def test_a_recording_with_bad_inputs_replays_to_the_same_counters_and_fixes(tmp_path: Path) -> None:
    scenario = demo_part(tmp_path)
    events = scenario_events(load_scenario(scenario))
    inputs = {ev.key: ev.msg for ev in reversed(events) if ev.key.startswith(f"{keys.ROOT}/sensor/")}
    junk = bad_payloads(inputs)
    (tan,) = [s for s in yaml.safe_load(scenario.read_text())["simulators"] if s["id"] == "tan1"]
    demo_nan = int(tan["params"]["nan_samples"])  # the demo's own NaN radio-altimeter samples (player/default)

    t0 = time.monotonic()
    a = run_stack(tmp_path, scenario, "a", scenario, junk)
    t_a = time.monotonic() - t0
    b = run_stack(tmp_path, scenario, "b", a["file"], [])
    t_b = time.monotonic() - t0 - t_a
    print(f"\nstack A (play the scenario) {t_a:.1f} s, stack B (replay the MCAP) {t_b:.1f} s")
    for name, st in a["status"].items():
        print(name, json.dumps(st["counters"]))
    print(json.dumps({k: len(v) for k, v in a["outputs"].items()}))

    # the recording holds every bad payload byte for byte: on fixstream/rejected/<key> unless it is a valid message
    # (one of the test's is: a string field set to "not this" on the PCL scan, which only the tracker refuses)
    kept = [decode_rejected(r) for r in iter_records(a["file"]) if r.topic.startswith(REJECTED_PREFIX)]
    kept_raw = Counter((k.key, k.payload, k.encoding) for k in kept)
    refused_junk = [j for j in junk if not _decodes(j)]
    assert not Counter(refused_junk) - kept_raw
    assert sum(kept_raw.values()) - len(refused_junk) == demo_nan
    assert (
        a["status"]["recorder/a"]["rejected_recorded"] == len(kept) == a["status"]["recorder/a"]["counters"]["rejected"]
    )

    assert all(
        a["status"][name]["scenario"]["ends"] == {"complete": 1} for name in ("terrain_nav/tan1", "pcl_tracker/rx1-fm")
    )
    # every service: the same status (counters, rejections by reason, seq, run ends, its own figures)
    for name in ("terrain_nav/tan1", "pcl_tracker/rx1-fm"):
        assert a["status"][name]["counters"]["rejected"] > 0, name
        assert comparable(a["status"][name]) == comparable(b["status"][name]), name
    # the recorder: the same, but for its own diagnostics (which it also records), aggregated per second of wall time
    assert recorder_figures(a["status"]["recorder/a"]) == recorder_figures(b["status"]["recorder/b"])
    # the fixes and tracks, message for message (header: stamp, seq, source), in order per key
    for key, msgs in a["outputs"].items():
        assert msgs, key
        assert b["outputs"][key] == msgs, key


def _decodes(item: Raw) -> bool:
    try:
        codec.decode(item[1], item[2])
    except codec.DecodeError:
        return False
    return True


def recorder_figures(status: dict[str, Any]) -> dict[str, Any]:
    """The recorder's status without what its own diagnostics add (``published`` counts them; it receives and writes
    each of them too) and without its names, paths and wall-clock figures."""
    c, own = status["counters"], status["counters"]["published"]
    return {
        "received": c["received"] - own,
        "accepted": c["accepted"] - own,
        "written": status["written"] - own,
        **{k: c[k] for k in ("rejected", "rejected_by_reason", "ignored", "dropped")},
        **{
            k: status[k]
            for k in ("rejected_recorded", "lost", "seq_gaps", "seq_jumps", "seq_resets", "duplicates", "write_errors")
        },
        **{k: status[k] for k in ("data_clock_ns", "runs", "services_seen")},
    }
