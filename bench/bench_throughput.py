"""Sustained throughput player -> router -> recorder, with loss counted three ways.

Real processes: a ``fixstream router``, a ``fixstream run recorder`` and ``fixstream play`` on a
generated scenario of four AUVs with five 1 kHz sensors each (20,000 sensor messages per second of
scenario time) played at ``--rate 1`` for ``BENCH_THROUGHPUT_DURATION_S`` (default 60 s). The player's
end marker says how many messages it published per key; the recorder's status says how many it wrote
and how many its per-publisher ``seq`` check found missing; the MCAP is read back and counted.
Target: 20,000 msg/s for 60 s with 0 lost.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from schemas import ScenarioMarker
from shared import codec
from shared.mcap_io import count_by_topic, recording_files
from shared.session import open_session
from shared.settings import ZenohSettings

from .report import emit
from .stack import REPO, router

DURATION_S = float(os.environ.get("BENCH_THROUGHPUT_DURATION_S", "60"))
RATE_HZ = 1000.0
PLATFORMS = 4


def scenario(duration_s: float) -> dict[str, object]:
    sims = []
    for p in range(PLATFORMS):
        name = f"auv{p}"
        sims.append(
            {
                "kind": "nav_platform",
                "id": name,
                "params": {
                    "platform": name,
                    "vehicle": "auv",
                    "truth_rate_hz": 10,
                    "start": {"position_m": [100.0 * p, 0.0, -30.0], "heading_deg": 10.0 * p, "speed_mps": 2.0},
                    "legs": [{"duration_s": duration_s, "turn_rate_dps": 0.5}],
                    "sensors": [
                        {"type": "dvl", "id": "dvl0", "rate_hz": RATE_HZ, "sigma_mps": 0.01},
                        {"type": "speed_log", "id": "log0", "rate_hz": RATE_HZ, "sigma_mps": 0.1},
                        {"type": "heading", "id": "gyro0", "rate_hz": RATE_HZ, "white_sigma_deg": 0.1},
                        {"type": "depth", "id": "press0", "rate_hz": RATE_HZ, "sigma_m": 0.05},
                        {"type": "heading", "id": "gyro1", "rate_hz": RATE_HZ, "white_sigma_deg": 0.2},
                    ],
                },
            }
        )
    return {
        "format": 1,
        "name": "bench_throughput",
        "description": "throughput benchmark",
        "seed": 1,
        "duration_s": duration_s,
        "frame_id": "local_enu",
        "wait_for": ["recorder/bench"],
        "wait_timeout_s": 30,
        "simulators": sims,
        "estimators": [],
    }


def recorder_status(endpoint: str) -> dict[str, object]:
    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    try:
        replies = list(session.get("fixstream/status/recorder/bench", timeout=5.0))
        ok = [r.ok for r in replies if r.ok is not None]
        return dict(json.loads(ok[0].payload.to_bytes())) if ok else {}
    finally:
        session.close()


def main() -> None:
    cmd = [sys.executable, "-m", "tools.cli.main", "--log-level", "WARNING"]
    with tempfile.TemporaryDirectory() as tmp, router() as endpoint:
        out_dir = Path(tmp) / "rec"
        scen = Path(tmp) / "bench.yaml"
        scen.write_text(yaml.safe_dump(scenario(DURATION_S)))
        env = dict(os.environ, FIXSTREAM_ZENOH_MODE="client", FIXSTREAM_ZENOH_CONNECT=endpoint)
        rec_env = dict(env, FIXSTREAM_RECORDER_INSTANCE="bench", FIXSTREAM_RECORDER_OUT_DIR=str(out_dir))
        recorder = subprocess.Popen([*cmd, "run", "recorder"], env=rec_env, cwd=REPO)
        markers: list[ScenarioMarker] = []
        watcher = open_session(ZenohSettings(mode="client", connect=[endpoint]))
        watcher.declare_subscriber(
            "fixstream/scenario/**",
            lambda s: markers.append(codec.decode(s.payload.to_bytes(), str(s.encoding))),  # type: ignore[arg-type]
        )
        t0 = time.monotonic()
        play = subprocess.run(
            [*cmd, "play", str(scen), "--rate", "1"], env=env, cwd=REPO, capture_output=True, text=True
        )
        wall = time.monotonic() - t0
        if play.returncode != 0:
            recorder.terminate()
            raise RuntimeError(f"player failed: {play.stderr[-2000:]}")
        # let the recorder catch up, then read its figures before stopping it
        deadline = time.monotonic() + 120
        status: dict[str, object] = {}
        last = -1
        while time.monotonic() < deadline:
            status = recorder_status(endpoint)
            written = int(status.get("written", 0))  # type: ignore[call-overload]
            if written == last:
                break
            last = written
            time.sleep(1.0)
        recorder.terminate()
        recorder.wait(timeout=60)
        watcher.close()
        counts: dict[str, int] = {}
        for f in recording_files(out_dir):
            for topic, n in count_by_topic(f).items():
                counts[topic] = counts.get(topic, 0) + n

    end = next(m for m in markers if m.event == "end")
    data_keys = ("fixstream/sensor/", "fixstream/truth/")
    recorded = sum(n for t, n in counts.items() if t.startswith(data_keys))
    sensor_truth_published = sum(n for t, n in end.published.items() if t.startswith(data_keys))
    lost_by_count = sensor_truth_published - recorded
    rate = recorded / wall
    rows = [
        (
            f"{DURATION_S:.0f} s",
            sensor_truth_published,
            recorded,
            lost_by_count,
            status.get("lost"),
            round(wall, 1),
            round(rate),
        )
    ]
    emit(
        "throughput",
        ["scenario", "published", "in MCAP", "lost (count)", "lost (seq)", "wall s", "msg/s sustained"],
        rows,
        {
            "duration_s": DURATION_S,
            "published": sensor_truth_published,
            "recorded": recorded,
            "lost_by_count": lost_by_count,
            "lost_by_seq": status.get("lost"),
            "wall_s": wall,
            "msg_per_s": rate,
            "target_msg_per_s": 20_000,
        },
    )


if __name__ == "__main__":
    main()
