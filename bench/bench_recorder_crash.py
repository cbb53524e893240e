"""What a SIGKILL costs the recorder, against its documented bound, over real processes.

A router, ``fixstream run recorder`` (``chunk_flush_s`` = ``BENCH_CRASH_FLUSH_S``, default 1.0, the default setting),
a witness subscriber that counts every sample (its count sampled every 20 ms), and publisher processes putting small
sensor messages on 4 keys at ``BENCH_CRASH_RATE`` msg/s in total (0: as fast as they can, the ``--rate 0`` case of
issue 14). After ``BENCH_CRASH_KILL_AT_S`` seconds the recorder is killed with SIGKILL; the killed file is read
(``shared.mcap_io``, up to its last complete chunk). Repeated ``BENCH_CRASH_REPEATS`` times per rate.

Figures per kill: what the witness had received at the kill, what the file holds, the loss as a count and as a
share of what was received, whether the file is a gap-free prefix per publisher, the data age of the newest message
in the file (the kill time minus its stamp: paced publishers stamp their messages on their own wall clock from the
start; "-" for unpaced ones, whose stamps follow their schedule, not the clock),
and the documented bound: ``rate x (chunk_flush_s + 0.1 s) + queue_size`` messages, i.e. the open chunk and the FIFO
(docs/recorder.md).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

from shared.mcap_io import decode_record, iter_records, recording_files

from .bench_recorder import _ANCHOR, _PUBLISHER, KEY_EXPR, PUBLISHERS
from .report import emit
from .stack import REPO, router

RATES = [float(r) for r in os.environ.get("BENCH_CRASH_RATE", "20000,0").split(",")]
KILL_AT_S = float(os.environ.get("BENCH_CRASH_KILL_AT_S", "6"))
REPEATS = int(os.environ.get("BENCH_CRASH_REPEATS", "3"))
FLUSH_S = float(os.environ.get("BENCH_CRASH_FLUSH_S", "1.0"))
QUEUE = 4096


def _kill_once(endpoint: str, tmp: Path, rate: float, index: int) -> dict[str, Any]:
    out_dir = tmp / f"rec-{int(rate)}-{index}"
    env = dict(
        os.environ,
        FIXSTREAM_ZENOH_MODE="client",
        FIXSTREAM_ZENOH_CONNECT=endpoint,
        FIXSTREAM_RECORDER_INSTANCE=f"crash{index}",
        FIXSTREAM_RECORDER_OUT_DIR=str(out_dir),
        FIXSTREAM_RECORDER_KEY_EXPR=KEY_EXPR,
        FIXSTREAM_RECORDER_CHUNK_FLUSH_S=str(FLUSH_S),
        FIXSTREAM_RECORDER_QUEUE_SIZE=str(QUEUE),
        FIXSTREAM_LOG_LEVEL="WARNING",
    )
    rec = subprocess.Popen([sys.executable, "-m", "tools.cli.main", "run", "recorder"], env=env, cwd=REPO)
    py = [sys.executable, "-c"]
    witness = subprocess.Popen(
        [*py, _ANCHOR, str(REPO), endpoint, KEY_EXPR, "0.02"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    # rate 0: as fast as possible (a very high paced rate that the publishers never reach)
    paced = rate if rate > 0 else 10_000_000.0
    pub = subprocess.Popen(
        [*py, _PUBLISHER, str(REPO), endpoint, "0", str(PUBLISHERS), str(paced), str(KILL_AT_S + 5), "block"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        for p in (witness, pub):
            assert p.stdout is not None and p.stdout.readline().strip() == "ready"
        time.sleep(4.0)  # the recorder is up and matched (its start takes ~2 s on a loaded machine)
        assert pub.stdin is not None
        t0 = time.monotonic()
        pub.stdin.write("go\n")
        pub.stdin.flush()
        time.sleep(KILL_AT_S)
        t_kill = time.monotonic()
        rec.send_signal(signal.SIGKILL)
        rec.wait(timeout=30)
        assert witness.stdin is not None and witness.stdout is not None
        pub.wait(timeout=60)
        witness.stdin.write("stop\n")
        witness.stdin.flush()
        lines = [json.loads(line) for line in witness.stdout]
    finally:
        for p in (rec, witness, pub):
            if p.poll() is None:
                p.kill()
                p.wait()
    series = [(line["t"], line["n"]) for line in lines if "t" in line]
    received_at_kill = max((n for t, n in series if t <= t_kill), default=0)
    (path,) = recording_files(out_dir)
    last_seq: dict[str, int] = {}
    gap_free = True
    newest_stamp = 0
    in_file = 0
    expected: dict[str, int] = defaultdict(int)
    for r in iter_records(path):
        msg = decode_record(r)
        src = msg.header.source
        gap_free &= msg.header.seq == expected[src]
        expected[src] = msg.header.seq + 1
        last_seq[src] = msg.header.seq
        newest_stamp = max(newest_stamp, msg.header.stamp_ns)
        in_file += 1
    achieved = received_at_kill / (t_kill - t0) if t_kill > t0 else 0.0
    bound = achieved * (FLUSH_S + 0.1) + QUEUE
    lost = max(received_at_kill - in_file, 0)
    return {
        "rate": rate,
        "achieved_msg_per_s": achieved,
        "received_at_kill": received_at_kill,
        "in_file": in_file,
        "lost": lost,
        "lost_share": lost / received_at_kill if received_at_kill else 0.0,
        "bound": bound,
        "within_bound": lost <= bound,
        "gap_free_prefix": gap_free,
        "newest_data_age_s": (t_kill - t0) - newest_stamp / 1e9,
    }


def main() -> None:
    rows = []
    with tempfile.TemporaryDirectory() as tmp, router() as endpoint:
        for rate in RATES:
            for i in range(REPEATS):
                rows.append(_kill_once(endpoint, Path(tmp), rate, i))
    emit(
        "recorder_crash",
        [
            "offered",
            "achieved msg/s",
            "received at kill",
            "in file",
            "lost",
            "lost share",
            "bound",
            "ok",
            "prefix",
            "data age s",
        ],
        [
            (
                "max" if r["rate"] == 0 else round(r["rate"]),
                round(r["achieved_msg_per_s"]),
                r["received_at_kill"],
                r["in_file"],
                r["lost"],
                f"{100 * r['lost_share']:.1f} %",
                round(r["bound"]),
                "yes" if r["within_bound"] else "NO",
                "yes" if r["gap_free_prefix"] else "NO",
                round(r["newest_data_age_s"], 2) if r["rate"] > 0 else "-",
            )
            for r in rows
        ],
        {"rows": rows, "chunk_flush_s": FLUSH_S, "queue_size": QUEUE, "kill_at_s": KILL_AT_S},
    )


if __name__ == "__main__":
    main()
