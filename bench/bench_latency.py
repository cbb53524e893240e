"""One-hop latency through the router: publisher session -> router process -> subscriber session.

The subscriber runs in its own process (as a service would); send and receive are stamped with
CLOCK_MONOTONIC (``time.monotonic_ns``), which is system-wide on Linux, so the two processes share
one clock. Messages are real ``BeaconRange`` payloads through the codec; latency is measured to
receipt (transport) and to a decoded, validated message (transport + decode).
Target: p99 under 2 ms at 1,000 msg/s.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import threading
import time
from typing import Any

import numpy as np
import zenoh

from schemas import BeaconRange, Header
from shared import codec
from shared.session import open_session
from shared.settings import ZenohSettings

from .report import emit
from .stack import router

RATE_HZ = float(os.environ.get("BENCH_LATENCY_RATE_HZ", "1000"))
DURATION_S = float(os.environ.get("BENCH_LATENCY_DURATION_S", "10"))
KEY = "fixstream/sensor/bench/range/b1"


def _subscriber(endpoint: str, n: int, ready: Any, out: Any) -> None:
    """Child process: receive n messages, return (transport, decoded) latencies in ms."""
    transport = np.full(n, np.nan)
    decoded = np.full(n, np.nan)
    done = threading.Event()
    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))

    def on_sample(s: zenoh.Sample) -> None:
        t_rx = time.monotonic_ns()
        msg = codec.decode(s.payload.to_bytes(), str(s.encoding))
        t_dec = time.monotonic_ns()
        i = msg.header.seq
        transport[i] = (t_rx - msg.header.stamp_ns) * 1e-6
        decoded[i] = (t_dec - msg.header.stamp_ns) * 1e-6
        if i == n - 1:
            done.set()

    sub = session.declare_subscriber(KEY, on_sample)
    ready.set()
    done.wait(timeout=DURATION_S + 30)
    sub.undeclare()
    session.close()
    out.put((transport, decoded))


def main() -> None:
    n = int(RATE_HZ * DURATION_S)
    enc = zenoh.Encoding(codec.encoding_of(BeaconRange))
    ctx = mp.get_context("spawn")
    with router() as endpoint:
        ready, out = ctx.Event(), ctx.Queue()
        child = ctx.Process(target=_subscriber, args=(endpoint, n, ready, out))
        child.start()
        ready.wait(timeout=30)
        session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
        pub = session.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK, express=True)
        time.sleep(0.5)
        period_ns = int(1e9 / RATE_HZ)
        t_next = time.monotonic_ns()
        for i in range(n):
            delay = t_next - time.monotonic_ns()
            if delay > 0:
                time.sleep(delay * 1e-9)
            t_next += period_ns
            msg = BeaconRange(header=Header(stamp_ns=time.monotonic_ns(), seq=i), beacon_id="b1", range_m=500.0)
            pub.put(codec.encode(msg), encoding=enc)
        transport, decoded = out.get(timeout=DURATION_S + 60)
        child.join(timeout=10)
        pub.undeclare()
        session.close()

    lost = int(np.isnan(transport).sum())
    rows = []
    figures: dict[str, object] = {"rate_hz": RATE_HZ, "duration_s": DURATION_S, "sent": n, "lost": lost}
    for label, arr in (("transport", transport), ("transport+decode", decoded)):
        ok = arr[~np.isnan(arr)]
        p50, p99, p999 = np.percentile(ok, [50, 99, 99.9])
        rows.append((label, n, lost, p50, p99, p999, float(ok.max())))
        figures[label.replace("+", "_")] = {"p50_ms": p50, "p99_ms": p99, "p999_ms": p999, "max_ms": float(ok.max())}
    emit("latency", ["path", "sent", "lost", "p50 ms", "p99 ms", "p99.9 ms", "max ms"], rows, figures)


if __name__ == "__main__":
    main()
