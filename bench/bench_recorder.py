"""Recorder throughput against its anchor, a bare Zenoh subscriber that only counts, in the same run.

Real processes on one router: ``fixstream run recorder`` (key ``fixstream/sensor/**``), an anchor subscriber (one
Python callback that increments a counter: the transport's cost into Python), and publisher processes putting small
sensor messages (msgpack ``Depth``, 82 bytes) on 4 keys, each with its own ``header.source`` and ``seq``, paced at
``BENCH_RECORDER_RATE`` msg/s in total for ``BENCH_RECORDER_DURATION_S`` s (defaults 100,000 and 60).

Loss is counted three ways: the publishers' own counts against the MCAP file, the recorder's seq check (``lost``),
and the anchor's count. The queue three ways: the FIFO's capacity (its bound), the largest backlog the recorder
drained at once (status ``fifo.peak_backlog``), and the largest lag between what the anchor and the recorder had
received at the same instant (sampled every 0.5 s). The recorder's status is asked every 0.5 s during the run
(answered / asked, slowest answer) and its stop after SIGTERM is timed.

Rows: BLOCK publishers at the target rate (the slowest subscriber holds them back, so the anchor cannot outrun the
recorder: the ratio is 1 by construction and the offered rate is what they managed); DROP publishers at the target
(the router drops for whichever subscriber falls behind: the ratio shows the recorder against the anchor) and at half
of it (what issue 14 saw hang). A recorder that cannot keep up loses at the router, and the loss must show in
``lost``.

``python -m bench.bench_recorder`` (or ``make bench``); ``BENCH_RECORDER_ROWS=block`` runs one row.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from shared.mcap_io import count_by_topic, recording_files
from shared.session import open_session
from shared.settings import ZenohSettings

from .procstat import THREAD_GROUPS, machine_busy_s, thread_cpu
from .report import emit
from .stack import REPO, router

DURATION_S = float(os.environ.get("BENCH_RECORDER_DURATION_S", "60"))
RATE = float(os.environ.get("BENCH_RECORDER_RATE", "100000"))
PUBLISHERS = 4
PROCS = int(os.environ.get("BENCH_RECORDER_PROCS", "2"))
#: rows: BLOCK publishers at the target, DROP publishers at the target, DROP at half the target (issue 14's case)
ROWS = os.environ.get("BENCH_RECORDER_ROWS", "block,drop,drop_half").split(",")
KEY_EXPR = "fixstream/sensor/**"

_PUBLISHER = r"""
import sys, time, json, msgpack, zenoh
sys.path.insert(0, sys.argv[1])
from shared.session import open_session
from shared.settings import ZenohSettings
ep, first, count, mode = sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[7]
rate, dur = float(sys.argv[5]), float(sys.argv[6])
cc = zenoh.CongestionControl.DROP if mode == "drop" else zenoh.CongestionControl.BLOCK
s = open_session(ZenohSettings(mode="client", connect=[ep]))
enc = zenoh.Encoding("application/msgpack;fixstream.Depth/1")
pubs, tmpls = [], []
for i in range(first, first + count):
    pubs.append(s.declare_publisher(f"fixstream/sensor/auv{i}/depth/d0", congestion_control=cc))
    header = {"stamp_ns": 0, "frame_id": "local_enu", "source": f"bench/p{i}", "seq": 0}
    tmpls.append({"header": header, "depth_m": 35.5})
print("ready", flush=True)
sys.stdin.readline()
per = rate / count
t0 = time.monotonic(); n = 0
while True:
    now = time.monotonic() - t0
    if now >= dur:
        break
    due = min(int(now * per) + 1, n + 200)  # never more than 200 rounds between looks at the clock
    while n < due:
        stamp = int(n * 1e9 / per)
        for p, t in zip(pubs, tmpls):
            h = t["header"]; h["seq"] = n; h["stamp_ns"] = stamp
            p.put(msgpack.packb(t), encoding=enc)
        n += 1
    time.sleep(0.001)
wall = time.monotonic() - t0
print(json.dumps({"sent": n * count, "wall_s": wall, "cpu_s": time.process_time()}), flush=True)
time.sleep(0.5)
s.close()
"""

_ANCHOR = r"""
import sys, time, json, threading, zenoh
sys.path.insert(0, sys.argv[1])
from shared.session import open_session
from shared.settings import ZenohSettings
s = open_session(ZenohSettings(mode="client", connect=[sys.argv[2]]))
n = [0]
def cb(sample):
    n[0] += 1
sub = s.declare_subscriber(sys.argv[3], cb)
print("ready", flush=True)
stop = threading.Event()
interval = float(sys.argv[4]) if len(sys.argv) > 4 else 0.5
def report():
    while not stop.wait(interval):
        print(json.dumps({"t": time.monotonic(), "n": n[0]}), flush=True)
threading.Thread(target=report, daemon=True).start()
sys.stdin.readline()
stop.set()
print(json.dumps({"final": n[0], "cpu_s": time.process_time()}), flush=True)
sub.undeclare(); s.close()
"""


def _cpu_s(pid: int) -> float:
    """User + system CPU time of a process so far, s (/proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _row(endpoint: str, tmp: Path, mode: str, rate: float) -> dict[str, Any]:
    py = [sys.executable, "-c"]
    out_dir = tmp / f"rec-{mode}-{rate:.0f}"  # one directory per row: two DROP rows must not count each other
    env = dict(
        os.environ,
        FIXSTREAM_ZENOH_MODE="client",
        FIXSTREAM_ZENOH_CONNECT=endpoint,
        FIXSTREAM_RECORDER_INSTANCE="bench",
        FIXSTREAM_RECORDER_OUT_DIR=str(out_dir),
        FIXSTREAM_RECORDER_KEY_EXPR=KEY_EXPR,
        FIXSTREAM_LOG_LEVEL="WARNING",
    )
    rec = subprocess.Popen([sys.executable, "-m", "tools.cli.main", "run", "recorder"], env=env, cwd=REPO)
    anchor = subprocess.Popen(
        [*py, _ANCHOR, str(REPO), endpoint, KEY_EXPR], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    per_proc = PUBLISHERS // PROCS
    pubs = [
        subprocess.Popen(
            [
                *py,
                _PUBLISHER,
                str(REPO),
                endpoint,
                str(i * per_proc),
                str(per_proc),
                str(rate / PROCS),
                str(DURATION_S),
                mode,
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        for i in range(PROCS)
    ]
    client = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    samples: list[tuple[float, int]] = []  # (monotonic, recorder received)
    asked = answered = 0
    slowest = 0.0
    stop_sampling = threading.Event()

    def status(timeout: float = 2.0) -> dict[str, Any]:
        replies = list(client.get("fixstream/status/recorder/bench", timeout=timeout))
        ok = [r.ok for r in replies if r.ok is not None]
        return dict(json.loads(ok[0].payload.to_bytes())) if ok else {}

    def sample() -> None:
        nonlocal asked, answered, slowest
        while not stop_sampling.wait(0.5):
            t = time.monotonic()
            asked += 1
            st = status()
            dt = time.monotonic() - t
            if st:
                answered += 1
                slowest = max(slowest, dt)
                samples.append((t + dt / 2, int(st["counters"]["received"])))

    try:
        for p in [anchor, *pubs]:
            assert p.stdout is not None
            assert p.stdout.readline().strip() == "ready"
        deadline = time.monotonic() + 30
        while not status(1.0) and time.monotonic() < deadline:
            time.sleep(0.2)
        time.sleep(1.0)  # publishers' declarations reach the recorder
        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        cpu_rec0, threads0, busy0 = _cpu_s(rec.pid), thread_cpu(rec.pid), machine_busy_s()
        t0 = time.monotonic()
        for p in pubs:
            assert p.stdin is not None
            p.stdin.write("go\n")
            p.stdin.flush()
        results = []
        for p in pubs:
            assert p.stdout is not None
            results.append(json.loads(p.stdout.readline()))
        busy_pub = machine_busy_s() - busy0
        pub_wall = max(r["wall_s"] for r in results)
        sent = sum(r["sent"] for r in results)
        # let the recorder catch up
        last, settled = -1, time.monotonic() + 60
        st: dict[str, Any] = {}
        while time.monotonic() < settled:
            st = status()
            if st and st["counters"]["received"] == last:
                break
            last = st["counters"]["received"] if st else last
            time.sleep(0.5)
        busy_wall = time.monotonic() - t0
        cpu_rec = _cpu_s(rec.pid) - cpu_rec0
        threads1 = thread_cpu(rec.pid)
        stop_sampling.set()
        sampler.join(timeout=5)
        assert anchor.stdin is not None and anchor.stdout is not None
        anchor.stdin.write("stop\n")
        anchor.stdin.flush()
        anchor_lines = [json.loads(line) for line in anchor.stdout]
        t_term = time.monotonic()
        rec.send_signal(signal.SIGTERM)
        rec.wait(timeout=180)
        stop_s = time.monotonic() - t_term
    finally:
        client.close()
        for p in [rec, anchor, *pubs]:
            if p.poll() is None:
                p.kill()
                p.wait()
    anchor_total = next(line["final"] for line in anchor_lines if "final" in line)
    anchor_cpu = next(line["cpu_s"] for line in anchor_lines if "final" in line)
    anchor_series = [(line["t"], line["n"]) for line in anchor_lines if "t" in line]
    lag = 0
    for t, n_rec in samples:  # the anchor's count at the same instant, interpolated
        before = [(ta, na) for ta, na in anchor_series if ta <= t]
        after = [(ta, na) for ta, na in anchor_series if ta >= t]
        if before and after:
            (t1, n1), (t2, n2) = before[-1], after[0]
            n_anchor = n1 if t2 == t1 else n1 + (n2 - n1) * (t - t1) / (t2 - t1)
            lag = max(lag, int(n_anchor - n_rec))
    in_mcap = sum(sum(count_by_topic(f).values()) for f in recording_files(out_dir))
    rec_rate = in_mcap / pub_wall
    anchor_rate = anchor_total / pub_wall
    return {
        "publishers": f"{PUBLISHERS} {mode.upper()}",
        "target_msg_per_s": rate,
        "offered_msg_per_s": sent / pub_wall,
        "duration_s": pub_wall,
        "sent": sent,
        "anchor_received": anchor_total,
        "anchor_msg_per_s": anchor_rate,
        "recorder_received": st.get("counters", {}).get("received"),
        "in_mcap": in_mcap,
        "recorder_msg_per_s": rec_rate,
        "ratio_to_anchor": in_mcap / anchor_total if anchor_total else None,
        "lost_by_count": sent - in_mcap,
        "lost_by_seq": st.get("lost"),
        "anchor_missed": sent - anchor_total,
        "fifo_capacity": st.get("fifo", {}).get("capacity"),
        "fifo_peak_backlog": st.get("fifo", {}).get("peak_backlog"),
        "max_lag_behind_anchor": lag,
        "status_answered": f"{answered}/{asked}",
        "status_slowest_s": slowest,
        "recorder_cpu_us_per_msg": 1e6 * cpu_rec / max(in_mcap, 1),
        "recorder_threads_us_per_msg": {g: 1e6 * (threads1[g] - threads0[g]) / max(in_mcap, 1) for g in threads0},
        "publishers_cpu_us_per_msg": 1e6 * sum(r["cpu_s"] for r in results) / max(sent, 1),
        "machine_cores_busy": busy_pub / pub_wall,
        "anchor_cpu_us_per_msg": 1e6 * anchor_cpu / max(anchor_total, 1),
        "catch_up_s": busy_wall - pub_wall,
        "stop_after_sigterm_s": stop_s,
        "recorder_exit": rec.returncode,
    }


def main() -> None:
    rows = []
    with tempfile.TemporaryDirectory() as tmp, router() as endpoint:
        for row in ROWS:
            mode, rate = ("drop", RATE / 2) if row == "drop_half" else (row, RATE)
            rows.append(_row(endpoint, Path(tmp), mode, rate))
    headers = [
        "publishers",
        "offered msg/s",
        "anchor msg/s",
        "recorder msg/s",
        "ratio",
        "lost (count)",
        "lost (seq)",
        "anchor missed",
        "FIFO peak / cap",
        "max lag",
        "status ok",
        "CPU µs/msg rec / anchor",
        "rec µs/msg: " + " / ".join(THREAD_GROUPS.values()),
        "publishers µs/msg",
        f"cores busy (of {os.cpu_count()})",
        "stop s",
    ]
    table = [
        (
            r["publishers"],
            round(r["offered_msg_per_s"]),
            round(r["anchor_msg_per_s"]),
            round(r["recorder_msg_per_s"]),
            round(r["ratio_to_anchor"], 3) if r["ratio_to_anchor"] is not None else None,
            r["lost_by_count"],
            r["lost_by_seq"],
            r["anchor_missed"],
            f"{r['fifo_peak_backlog']} / {r['fifo_capacity']}",
            r["max_lag_behind_anchor"],
            r["status_answered"],
            f"{r['recorder_cpu_us_per_msg']:.1f} / {r['anchor_cpu_us_per_msg']:.1f}",
            " / ".join(f"{r['recorder_threads_us_per_msg'][g]:.1f}" for g in THREAD_GROUPS),
            f"{r['publishers_cpu_us_per_msg']:.1f}",
            f"{r['machine_cores_busy']:.2f}",
            round(r["stop_after_sigterm_s"], 2),
        )
        for r in rows
    ]
    emit(
        "recorder",
        headers,
        table,
        {"rows": rows, "target_msg_per_s": RATE, "duration_s": DURATION_S, "machine_cpus": os.cpu_count()},
    )


if __name__ == "__main__":
    main()
