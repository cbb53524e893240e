"""The player flat out (``--rate 0``) beside a bare Zenoh publisher of the same bytes, in the same run.

Scenario: the throughput benchmark's four AUVs, five 1 kHz sensors each plus truth at 10 Hz
(:func:`bench.bench_throughput.scenario`), ``BENCH_PLAYER_DURATION_S`` (default 10 s) of scenario time, about
20,000 messages per scenario second. A counting subscriber in its own process (a client of the router, as the
recorder is) stamps the first and the last data message it receives; rate = messages / (last - first).

* **anchor**: a bare zenoh publisher in its own process putting the player's exact payloads, encoded beforehand
  (one reliable, blocking publisher per key, as the player declares them): what the transport takes from Python.
* **fixstream play --rate 0**: the real command, generating and encoding as it publishes.
* **generation only**: the player's encoded stream (:func:`services.player.wire.wire_events`) built in this
  process with no Zenoh: what the player would reach on a free transport.

Each publisher runs ``BENCH_PLAYER_REPEATS`` times (default 3), anchor and player alternating, after one player run
that is not counted (the first run on a fresh router is often the slowest); the table gives the median run and
lists every run (the machine is shared: single runs vary by a factor of two). Target (issue 18): the player
>= 100,000 msg/s. ``BENCH_PLAYER_BASELINE=<checkout>`` adds a row for the player of another checkout (e.g. the
commit before this benchmark) with the same interpreter.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import yaml

from .bench_throughput import scenario
from .report import emit
from .stack import REPO, router

DURATION_S = float(os.environ.get("BENCH_PLAYER_DURATION_S", "10"))
REPEATS = int(os.environ.get("BENCH_PLAYER_REPEATS", "3"))
BASELINE = os.environ.get("BENCH_PLAYER_BASELINE", "")
TARGET_MSG_PER_S = 100_000
COUNTER = "benchcount"
DATA_KEYS = ("fixstream/sensor/**", "fixstream/truth/**")


def _counter(endpoint: str, expected: int, instance: str, ready: Any, out: Any) -> None:
    """Child process: count data messages until ``expected`` arrived (or 20 s of silence); report (n, first, last)."""
    from shared import keys
    from shared.session import open_session
    from shared.settings import ZenohSettings

    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    state = {"n": 0, "first": 0.0, "last": 0.0}
    done = threading.Event()

    def on_sample(_sample: object) -> None:
        now = time.perf_counter()
        state["n"] += 1
        if state["n"] == 1:
            state["first"] = now
        state["last"] = now
        if state["n"] >= expected:
            done.set()

    subs = [session.declare_subscriber(k, on_sample) for k in DATA_KEYS]
    token = session.liveliness().declare_token(keys.alive(COUNTER, instance))
    ready.set()
    seen = -1
    while not done.wait(20.0) and state["n"] != seen:  # stop after 20 s without a message
        seen = state["n"]
    token.undeclare()
    for sub in subs:
        sub.undeclare()
    out.put((state["n"], state["first"], state["last"]))
    session.close()


def _anchor(endpoint: str, path: str, instance: str, out: Any) -> None:
    """Child process: put the player's payloads, encoded beforehand, with bare zenoh publishers; report put time."""
    import zenoh

    from services.player.player import wait_for_alive
    from services.player.scenario import load_scenario
    from services.player.timeline import build, player_source
    from services.player.wire import wire_events
    from shared import codec, keys
    from shared.session import open_session
    from shared.settings import ZenohSettings

    sc = load_scenario(path)
    wire = [
        (w.key, codec.zenoh_encoding(w.encoding), w.payload)
        for w in wire_events(build(sc, sc.seed), player_source("anchor"))
    ]
    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    pubs = {
        k: session.declare_publisher(
            k, congestion_control=zenoh.CongestionControl.BLOCK, reliability=zenoh.Reliability.RELIABLE
        )
        for k in dict.fromkeys(k for k, _, _ in wire)
    }
    wait_for_alive(session, [keys.alive(COUNTER, instance)], 30.0)
    items = [(pubs[k].put, enc, payload) for k, enc, payload in wire]
    t0 = time.perf_counter()
    for put, enc, payload in items:
        put(payload, encoding=enc)
    out.put(time.perf_counter() - t0)
    time.sleep(0.5)
    session.close()


def _run(endpoint: str, path: Path, expected: int, what: str, instance: str) -> dict[str, float]:
    """One publisher run against a fresh counting subscriber: received, first-to-last time and rate."""
    ctx = mp.get_context("spawn")
    ready, out = ctx.Event(), ctx.Queue()
    counter = ctx.Process(target=_counter, args=(endpoint, expected, instance, ready, out))
    counter.start()
    if not ready.wait(30):
        raise RuntimeError("counting subscriber did not start")
    pub_s = float("nan")
    if what == "anchor":
        pub_out = ctx.Queue()
        anchor = ctx.Process(target=_anchor, args=(endpoint, str(path), instance, pub_out))
        anchor.start()
        pub_s = pub_out.get(timeout=600)
        anchor.join(timeout=60)
    else:
        env = {k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_")}
        if what == "baseline":
            env["PYTHONPATH"] = BASELINE
        cmd = [sys.executable, "-m", "tools.cli.main", "--log-level", "INFO", "play", str(path), "--rate", "0"]
        cmd += ["--connect", endpoint, "--wait-for", f"{COUNTER}/{instance}", "--linger", "0.2"]
        done = subprocess.run(cmd, env=env, cwd=BASELINE or REPO, capture_output=True, text=True, timeout=600)
        if done.returncode != 0:
            raise RuntimeError(f"player failed: {done.stderr[-2000:]}")
        for line in (done.stdout + done.stderr).splitlines():
            if "published" in line and " in " in line:
                pub_s = float(line.rsplit(" in ", 1)[1].split()[0])
    n, first, last = out.get(timeout=120)
    counter.join(timeout=30)
    span = last - first
    return {"received": n, "span_s": span, "msg_per_s": n / span if span > 0 else float("nan"), "publisher_s": pub_s}


def _generation_only(path: Path) -> dict[str, float]:
    from services.player.scenario import load_scenario
    from services.player.timeline import build, player_source
    from services.player.wire import wire_events

    sc = load_scenario(path)
    t0 = time.perf_counter()
    n = sum(1 for _ in wire_events(build(sc, sc.seed), player_source("default")))
    span = time.perf_counter() - t0
    return {"received": n, "span_s": span, "msg_per_s": n / span, "publisher_s": span}


def _median(runs: list[dict[str, float]]) -> dict[str, float]:
    return sorted(runs, key=lambda r: r["msg_per_s"])[len(runs) // 2]


def main() -> None:
    doc = scenario(DURATION_S)
    doc["wait_for"] = []
    with tempfile.TemporaryDirectory() as tmp, router() as endpoint:
        path = Path(tmp) / "bench_player.yaml"
        path.write_text(yaml.safe_dump(doc))
        gen = _generation_only(path)
        expected = int(gen["received"])
        runs: dict[str, list[dict[str, float]]] = {"anchor": [], "player": []}
        if BASELINE:
            runs["baseline"] = []
        _run(endpoint, path, expected, "player", "warmup")  # not counted: the first run of a fresh router is slower
        for r in range(REPEATS):
            for what in runs:
                runs[what].append(_run(endpoint, path, expected, what, f"{what}{r}"))
    med = {what: _median(rs) for what, rs in runs.items()}
    anchor = med["anchor"]["msg_per_s"]
    labels = {
        "anchor": "bare zenoh publisher, pre-encoded bytes (anchor)",
        "player": "fixstream play --rate 0",
        "baseline": f"fixstream play --rate 0 of {BASELINE}",
    }
    rows = []
    for what, m in med.items():
        rows.append(
            (
                labels[what],
                expected,
                int(m["received"]),
                round(m["span_s"], 2),
                round(m["msg_per_s"]),
                round(m["msg_per_s"] / anchor, 2),
                ", ".join(f"{x['msg_per_s'] / 1000:.0f}k" for x in runs[what]),
            )
        )
    rows.append(
        (
            "generation + encoding only, no Zenoh",
            expected,
            expected,
            round(gen["span_s"], 2),
            round(gen["msg_per_s"]),
            round(gen["msg_per_s"] / anchor, 2),
            "",
        )
    )
    emit(
        "player",
        ["publisher", "published", "received", "first-last s", "msg/s", "ratio to anchor", "all runs"],
        rows,
        {
            "duration_s": DURATION_S,
            "messages": expected,
            "repeats": REPEATS,
            "runs": runs,
            "generation_only": gen,
            "anchor_msg_per_s": anchor,
            "player_msg_per_s": med["player"]["msg_per_s"],
            "ratio": med["player"]["msg_per_s"] / anchor,
            "target_msg_per_s": TARGET_MSG_PER_S,
            "statistic": "median of the runs (rate at a separate counting subscriber, first to last message)",
        },
    )


if __name__ == "__main__":
    main()
