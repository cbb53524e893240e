"""What the Foxglove bridge's WebSocket front costs (tools/foxglove_front.py): latency and delivery through the
front against a client connected to the SDK server directly, at paced message rates.

One foxglove-sdk server (TLS on loopback, as the bridge runs it) and the front; a JSON channel of ~300-byte messages
logged at ``rate`` Hz for ``duration_s``; two clients subscribed at the same time, one through the front, one
direct (trusting the run's certificate). Latency = receive time − the message's log time (both the wall clock of
this one machine), per message; delivered = messages received / logged (the SDK's per-client backlog drops the
oldest when a client falls behind).
"""

from __future__ import annotations

import asyncio
import json
import struct
import threading
import time
from typing import Any

import numpy as np

from .report import emit

RATES_HZ = (500, 2000, 5000)
DURATION_S = 3.0


async def _client(url: str, ssl_ctx: Any, topic: str, ready: threading.Event, latencies: list[float]) -> None:
    import websockets

    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"], ssl=ssl_ctx, max_size=None) as ws:  # type: ignore[list-item]
        subscribed = False
        while True:
            try:
                frame = await asyncio.wait_for(ws.recv(), 2.0)
            except TimeoutError:
                return
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "advertise" and not subscribed:
                    for ch in msg["channels"]:
                        if ch["topic"] == topic:
                            await ws.send(
                                json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": ch["id"]}]})
                            )
                            subscribed = True
                            await asyncio.sleep(0.3)
                            ready.set()
                continue
            if frame[0] == 1:
                (log_ns,) = struct.unpack("<Q", frame[5:13])
                latencies.append((time.time_ns() - log_ns) / 1e6)


def _run(rate_hz: int) -> dict[str, float]:
    import foxglove
    from foxglove import Channel, Schema

    from tools.foxglove_front import Front, OriginPolicy, UpstreamTls

    tls = UpstreamTls.make()
    ctx = foxglove.Context()
    server = foxglove.start_server(
        name="bench", host="127.0.0.1", port=0, context=ctx, tls_cert=tls.cert_pem, tls_key=tls.key_pem
    )
    front = Front("127.0.0.1", 0, server.port, tls, OriginPolicy())
    port = front.start()
    topic = "fixstream/bench/x"
    channel = Channel(
        topic, schema=Schema(name="X", encoding="jsonschema", data=b"{}"), message_encoding="json", context=ctx
    )
    payload = json.dumps({"pad": "x" * 280}).encode()
    results: dict[str, list[float]] = {"front": [], "direct": []}
    readies = {k: threading.Event() for k in results}
    threads = [
        threading.Thread(
            target=lambda k=k, u=u, s=s: asyncio.run(_client(u, s, topic, readies[k], results[k])), daemon=True
        )
        for k, u, s in (
            ("front", f"ws://127.0.0.1:{port}", None),
            ("direct", f"wss://127.0.0.1:{server.port}", tls.client_context()),
        )
    ]
    for t in threads:
        t.start()
    channel.log(payload)  # the channel exists once it is logged to: the clients see it advertised
    for r in readies.values():
        r.wait(10)
    n = int(rate_hz * DURATION_S)
    t0 = time.monotonic()
    for i in range(n):
        delay = t0 + i / rate_hz - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        channel.log(payload, log_time=time.time_ns())
    for t in threads:
        t.join(10)
    front.stop()
    server.stop()
    out: dict[str, float] = {}
    for k, lat in results.items():
        a = np.array(lat)
        out[f"{k}_delivered"] = len(a) / n
        out[f"{k}_p50_ms"] = float(np.percentile(a, 50)) if len(a) else float("nan")
        out[f"{k}_p99_ms"] = float(np.percentile(a, 99)) if len(a) else float("nan")
    return out


def main() -> None:
    rows = []
    figures = {}
    for rate in RATES_HZ:
        r = _run(rate)
        figures[str(rate)] = {k: round(v, 4) for k, v in r.items()}
        rows.append(
            (
                rate,
                r["direct_delivered"],
                r["front_delivered"],
                r["direct_p50_ms"],
                r["front_p50_ms"],
                r["direct_p99_ms"],
                r["front_p99_ms"],
            )
        )
    emit(
        "foxglove_front",
        [
            "rate Hz",
            "delivered direct",
            "delivered front",
            "p50 ms direct",
            "p50 ms front",
            "p99 ms direct",
            "p99 ms front",
        ],
        rows,
        {"duration_s": DURATION_S, "payload_bytes": 300, "per_rate": figures},
    )


if __name__ == "__main__":
    main()
