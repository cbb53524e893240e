"""What a router outage loses, with plain Zenoh publishers and subscribers and with zenoh-ext's advanced ones.

docs/stack.md ("When the router restarts"): what is published while no router routes it is lost for every
subscriber, and a loss at the tail of a key shows in no seq check (the recorder counts a player's tail against its
end marker, ``lost_at_end``). zenoh-ext offers the publication cache, miss detection and recovery that would bring
such messages back. This benchmark measures whether they do, before fixstream adopts them. The anchor is plain
pub/sub in the same run.

Real processes, client mode, one ``fixstream router`` on loopback: a subscriber process and a publisher process per
mode. The publisher puts on four keys: ``k0`` and ``k1`` at 10 Hz for the whole run, ``k2`` at 10 Hz until its last
sample, published during the outage (a tail), and ``k3`` one sample only, during the outage. The router is killed
(SIGKILL) ``KILL_S`` after the start and started again on the same port ``OUTAGE_S`` later. Reported per mode:
what was published, during the outage, what arrived (unique seqs), what was lost, whether the tail and the lone
sample arrived, duplicates, samples out of order, and when the last sample of the outage arrived, counted from the
router's restart.

Advanced mode: ``declare_advanced_publisher(cache=CacheConfig(max_samples=100),
sample_miss_detection=MissDetectionConfig(heartbeat=0.5), publisher_detection=True)`` and
``declare_advanced_subscriber(history=HistoryConfig(detect_late_publishers=True),
recovery=RecoveryConfig(heartbeat=True), subscriber_detection=True)``.

``python -m bench outage_recovery``
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from itertools import pairwise
from pathlib import Path
from typing import Any

import zenoh

from shared.session import free_tcp_port, open_session
from shared.settings import ZenohSettings

from .report import emit
from .stack import REPO, start_router

KEYS = ("bench/outage/k0", "bench/outage/k1", "bench/outage/k2", "bench/outage/k3")
RATE_HZ = 10.0
KILL_S = 2.0
OUTAGE_S = 3.0
PUBLISH_END_S = 9.0
#: k2's last sample and k3's only one, both while the router is down
TAIL_S = KILL_S + 1.5
LONE_S = KILL_S + 1.0
RUN_S = 15.0
MODES = ("plain", "advanced")


def _session(endpoint: str) -> zenoh.Session:
    return open_session(ZenohSettings(mode="client", connect=[endpoint], connect_timeout_s=10.0))


def publish(endpoint: str, t0: float, mode: str, out: str) -> None:
    """The publisher process: the schedule of the module docstring; writes {key: [(seq, sent at s)]}."""
    import zenoh.ext as zx

    session = _session(endpoint)
    if mode == "plain":
        pubs: dict[str, Any] = {k: session.declare_publisher(k) for k in KEYS}
    else:
        pubs = {
            k: zx.declare_advanced_publisher(
                session,
                k,
                cache=zx.CacheConfig(max_samples=100),
                sample_miss_detection=zx.MissDetectionConfig(heartbeat=0.5),
                publisher_detection=True,
            )
            for k in KEYS
        }
    sent: dict[str, list[tuple[int, float]]] = {k: [] for k in KEYS}

    def put(key: str, now: float) -> None:
        seq = len(sent[key])
        pubs[key].put(json.dumps({"seq": seq}))
        sent[key].append((seq, round(now, 3)))

    while (now := time.time() - t0) < RUN_S - 1.0:  # alive to the end: the cache lives in this process
        if 0.5 <= now <= PUBLISH_END_S:
            for key in KEYS[:2]:
                put(key, now)
            if now <= TAIL_S:
                put(KEYS[2], now)
        if now >= LONE_S and not sent[KEYS[3]]:
            put(KEYS[3], now)
        time.sleep(1.0 / RATE_HZ)
    Path(out).write_text(json.dumps(sent))
    session.close()


def subscribe(endpoint: str, t0: float, mode: str, out: str) -> None:
    """The subscriber process: every sample's (key, seq, arrival s); writes them and what the miss listener said."""
    import zenoh.ext as zx

    session = _session(endpoint)
    got: list[tuple[str, int, float]] = []
    misses: list[tuple[float, int]] = []
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        seq = json.loads(sample.payload.to_bytes())["seq"]
        with lock:
            got.append((str(sample.key_expr), seq, round(time.time() - t0, 3)))

    if mode == "plain":
        sub: Any = session.declare_subscriber("bench/outage/**", on_sample)
    else:
        sub = zx.declare_advanced_subscriber(
            session,
            "bench/outage/**",
            on_sample,
            history=zx.HistoryConfig(detect_late_publishers=True),
            recovery=zx.RecoveryConfig(heartbeat=True),
            subscriber_detection=True,
        )
        sub.sample_miss_listener(lambda m: misses.append((round(time.time() - t0, 3), int(m.nb))))
    print("ready", flush=True)
    while time.time() - t0 < RUN_S:
        time.sleep(0.1)
    with lock:
        Path(out).write_text(json.dumps({"got": got, "misses": misses}))
    session.close()


def run_mode(mode: str, tmp: Path) -> dict[str, Any]:
    """One run of ``mode``: router, subscriber, publisher, the outage; the figures of the module docstring."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    router = start_router(endpoint)
    pub_out, sub_out = tmp / f"{mode}-pub.json", tmp / f"{mode}-sub.json"
    t0 = time.time() + 3.0  # both sessions open before the schedule starts
    role = [sys.executable, "-m", "bench.bench_outage_recovery"]
    sub = subprocess.Popen([*role, "sub", endpoint, str(t0), mode, str(sub_out)], cwd=REPO, stdout=subprocess.PIPE)
    pub = subprocess.Popen([*role, "pub", endpoint, str(t0), mode, str(pub_out)], cwd=REPO)
    try:
        time.sleep(max(0.0, t0 + KILL_S - time.time()))
        router.send_signal(signal.SIGKILL)
        router.wait()
        time.sleep(max(0.0, t0 + KILL_S + OUTAGE_S - time.time()))
        router = start_router(endpoint)
        up_s = time.time() - t0
        pub.wait(timeout=RUN_S + 30)
        sub.wait(timeout=RUN_S + 30)
    finally:
        router.terminate()
        router.wait(timeout=10)
        for p in (pub, sub):
            if p.poll() is None:
                p.kill()
    sent: dict[str, list[list[float]]] = json.loads(pub_out.read_text())
    received = json.loads(sub_out.read_text())
    got: dict[str, list[tuple[int, float]]] = {k: [] for k in KEYS}
    for key, seq, at in received["got"]:
        got[key].append((int(seq), float(at)))
    published = sum(len(v) for v in sent.values())
    during = {(k, int(s)) for k, v in sent.items() for s, at in v if KILL_S <= at <= KILL_S + OUTAGE_S}
    unique = {(k, s) for k, v in got.items() for s, _ in v}
    late = [at for k, v in got.items() for s, at in v if (k, s) in during]
    seqs = {k: [s for s, _ in v] for k, v in got.items()}
    return {
        "published": published,
        "during_outage": len(during),
        "received_unique": len(unique),
        "lost": published - len(unique),
        "tail_arrived": (KEYS[2], int(sent[KEYS[2]][-1][0])) in unique,
        "lone_arrived": (KEYS[3], 0) in unique,
        "duplicates": sum(len(v) - len(set(v)) for v in seqs.values()),
        "out_of_order": sum(1 for v in seqs.values() for a, b in pairwise(v) if b < a),
        "last_outage_sample_after_restart_s": round(max(late) - up_s, 2) if late else None,
        "misses_reported": sum(n for _, n in received["misses"]),
    }


def main() -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        results = {mode: run_mode(mode, Path(tmp)) for mode in MODES}
    headers = [
        "mode",
        "published",
        "during outage",
        "arrived",
        "lost",
        "tail arrived",
        "lone sample arrived",
        "duplicates",
        "out of order",
        "last outage sample, s after restart",
        "misses reported",
    ]
    rows = [
        [
            mode,
            r["published"],
            r["during_outage"],
            r["received_unique"],
            r["lost"],
            r["tail_arrived"],
            r["lone_arrived"],
            r["duplicates"],
            r["out_of_order"],
            r["last_outage_sample_after_restart_s"],
            r["misses_reported"],
        ]
        for mode, r in results.items()
    ]
    emit("outage_recovery", headers, rows, {"kill_s": KILL_S, "outage_s": OUTAGE_S, **results})


if __name__ == "__main__":
    if len(sys.argv) == 6 and sys.argv[1] in ("pub", "sub"):
        role, endpoint, start, mode_, out_ = sys.argv[1:]
        (publish if role == "pub" else subscribe)(endpoint, float(start), mode_, out_)
    else:
        main()
