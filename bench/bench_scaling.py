"""How cost grows with the fleet: N terrain_nav vehicles, N service processes, one router (issue 18, item 4).

For each N in ``BENCH_SCALING_N`` (default 1, 10, 50, 100, 200): one ``fixstream router``, N ``fixstream run
terrain_nav`` processes (instance and vehicle ``v000`` ...; the informative map, the digest's defaults), and the
player on a scenario of N ``terrain_nav`` aircraft (INS and radio altimeter at 20 Hz each, about 41 sensor messages
per second per vehicle) played at ``BENCH_SCALING_RATE`` (default 1) times real time for ``BENCH_SCALING_DURATION_S``
(default 40) s of scenario time. An observer process (a client of the router like the services) stamps, on one
clock (``CLOCK_MONOTONIC``, system-wide), the arrival of every sensor message and of every output.

* **CPU per message**: the services' CPU time (user + system from ``/proc``, all N processes) from the start of
  play until they have worked off their queues, less their idle CPU over that time, divided by the sensor messages
  they received; the same for the router. Idle CPU is measured over ``IDLE_S`` before play; the services' is
  reported apart (what N waiting processes cost). "cores busy": services and router, idle included, over the window.
* **End-to-end latency**: for each output (``TerrainVerdict`` and ``TerrainFix``), its arrival minus the arrival
  of the input that released it. A terrain_nav output of stamp ``s`` is made when an input stamped ``s + d`` or
  later is processed: ``d`` is the reorder window (0.1 s, ``services/terrain_nav/service.py``) plus the core's own
  wait for the end of its group of cell measurements (together 450 ms). ``d`` is calibrated per output kind on the
  first (smallest, unloaded) N, where the releasing input is simply the last one that arrived before the output
  (the most common offset, to the ms), and then held fixed, so that at larger N a service that falls behind shows
  as latency instead of hiding it. The releasing input is then the first of the vehicle stamped at least
  ``s + d``. Outputs released otherwise (the end-of-run flush, a verdict on a gap: no such input, or one that
  arrived after them) are left out; "outputs timed" counts the rest. Both arrivals are seen by the same observer
  through the same router, so the figure is router -> service -> router, queueing included.

Where it stops: each service takes ~35–45 MB (PSS, measured on the N = 1 run; ~108 MB before service processes
stopped importing every estimator through the plugin registry) and ~1 s of CPU to start. An N whose
estimated memory (N x PSS x 1.3) exceeds ``MEM_FRACTION`` of MemAvailable is not started; the row says why.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .report import emit
from .service_harness import CLI, client_env, cpu_s
from .stack import REPO, router

N_LIST = [int(n) for n in os.environ.get("BENCH_SCALING_N", "1,10,50,100,200").split(",")]
DURATION_S = float(os.environ.get("BENCH_SCALING_DURATION_S", "40"))
RATE = float(os.environ.get("BENCH_SCALING_RATE", "1"))
MEM_FRACTION = float(os.environ.get("BENCH_SCALING_MEM_FRACTION", "0.5"))
IDLE_S = 5.0
REORDER_NS = 100_000_000  # terrain_nav's reorder_s default, ns (the release offset if none can be calibrated)
MAP = "scenarios/maps/terrain_nav_informative.npy"
DEFAULT_PSS_MB = 90.0


def vehicle(i: int) -> str:
    return f"v{i:03d}"


def scenario(n: int) -> dict[str, Any]:
    sims = [
        {
            "kind": "terrain_nav",
            "id": vehicle(i),
            "params": {"platform": vehicle(i), "terrain": "informative", "terrain_seed": 1, "map_file": MAP},
        }
        for i in range(n)
    ]
    return {
        "format": 1,
        "name": f"bench_scaling_{n}",
        "seed": 1,
        "duration_s": DURATION_S,
        "frame_id": "map_enu",
        "simulators": sims,
    }


def _observer(endpoint: str, ready: Any, stop: Any, out: Any) -> None:
    """Child process: arrival time and payload of every sensor message and every terrain output, until ``stop``."""
    from shared import codec
    from shared.session import open_session
    from shared.settings import ZenohSettings

    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    inputs: list[tuple[str, int, bytes]] = []
    outputs: list[tuple[str, int, bytes]] = []
    last = [time.monotonic()]

    def on_input(s: Any) -> None:
        inputs.append((str(s.key_expr), time.monotonic_ns(), s.payload.to_bytes()))

    def on_output(s: Any) -> None:
        outputs.append((str(s.key_expr), time.monotonic_ns(), s.payload.to_bytes()))
        last[0] = time.monotonic()

    subs = [
        session.declare_subscriber("fixstream/sensor/**", on_input),
        session.declare_subscriber("fixstream/fix/terrain/**", on_output),
    ]
    ready.set()
    stop.wait()
    for sub in subs:
        sub.undeclare()

    def compact(items: list[tuple[str, int, bytes]], chunk: int) -> list[tuple[str, int, int]]:
        """(vehicle: key chunk ``chunk``, arrival ns, header stamp ns) of each message."""
        rows = []
        for key, t, payload in items:
            header = codec.peek_header(payload)
            if header is not None:
                rows.append((key.split("/")[chunk], t, header[2]))
        return rows

    # fixstream/sensor/<vehicle>/..., fixstream/fix/terrain/<vehicle>[/verdict]
    kinds = ["/".join(key.split("/")[4:]) for key, _, _ in outputs]
    out.put((compact(inputs, 2), [(*row, kind) for row, kind in zip(compact(outputs, 3), kinds, strict=True)]))
    session.close()


def _pss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
        if line.startswith("Pss:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _mem_available_mb() -> float:
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemAvailable:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _wait_alive(endpoint: str, names: list[str], timeout_s: float) -> None:
    from services.player.player import wait_for_alive
    from shared import keys
    from shared.session import open_session
    from shared.settings import ZenohSettings

    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    try:
        wait_for_alive(session, [keys.alive("terrain_nav", v) for v in names], timeout_s)
    finally:
        session.close()


def _router_pid(endpoint: str) -> int | None:
    """The pid of the ``fixstream router`` listening on ``endpoint`` (a child of this process)."""
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"router" in cmd and endpoint.encode() in cmd:
            return int(pid)
    return None


def _by_vehicle(inputs: list[tuple[str, int, int]]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per vehicle: arrival times and stamps of its inputs, in arrival order (one subscription: the player's order,
    stamp order per vehicle)."""
    lists: dict[str, tuple[list[int], list[int]]] = {}
    for v, t, stamp in inputs:
        arrivals, stamps = lists.setdefault(v, ([], []))
        arrivals.append(t)
        stamps.append(stamp)
    return {v: (np.asarray(a), np.asarray(s)) for v, (a, s) in lists.items()}


def _kind(key_tail: str) -> str:
    return key_tail or "fix"


def release_offsets_ns(inputs: list[tuple[str, int, int]], outputs: list[tuple[str, int, int, str]]) -> dict[str, int]:
    """Per output kind (fix, verdict): the data time between an output's stamp and the stamp of the input that
    released it, from a run without backlog (where the releasing input is the last one of the vehicle that arrived
    before the output): the most common value, to the ms. That is the service's release rule (terrain_nav: 450 ms,
    the reorder window and the core's wait for the end of its group); the few outputs released otherwise (the
    end-of-run flush, a verdict on a gap) come out with a negative latency below and are not timed."""
    by_vehicle = _by_vehicle(inputs)
    offsets: dict[str, list[int]] = {}
    for v, t, stamp, kind in outputs:
        if v in by_vehicle:
            arrivals, stamps = by_vehicle[v]
            i = int(np.searchsorted(arrivals, t, side="left")) - 1
            if i >= 0:
                offsets.setdefault(kind, []).append(int(stamps[i]) - stamp)
    modes = {}
    for kind, values in offsets.items():
        ms, counts = np.unique(np.round(np.asarray(values) / 1e6).astype(np.int64), return_counts=True)
        modes[kind] = int(ms[np.argmax(counts)]) * 1_000_000
    return modes


def latencies_ms(
    inputs: list[tuple[str, int, int]], outputs: list[tuple[str, int, int, str]], offsets: dict[str, int]
) -> np.ndarray:
    """Per output: its arrival minus the arrival of the first input of its vehicle stamped at least its stamp plus
    the release offset of its kind; outputs released otherwise (negative) are left out."""
    by_vehicle = _by_vehicle(inputs)
    out = []
    for v, t, stamp, kind in outputs:
        if v not in by_vehicle or kind not in offsets:
            continue
        arrivals, stamps = by_vehicle[v]
        i = int(np.searchsorted(stamps, stamp + offsets[kind], side="left"))
        if i < len(stamps) and t >= arrivals[i]:
            out.append((t - int(arrivals[i])) / 1e6)
    return np.asarray(out)


def run_n(n: int, pss_mb: float, offsets: dict[str, int] | None) -> dict[str, Any]:
    """One N; ``offsets``: the release offsets per output kind (None: calibrate them on this run, which must be
    without backlog)."""
    need_mb = n * pss_mb * 1.3
    avail = _mem_available_mb()
    if need_mb > MEM_FRACTION * avail:
        return {
            "n": n,
            "skipped": f"needs ~{need_mb / 1024:.1f} GiB ({n} x {pss_mb:.0f} MB x 1.3), "
            f"{MEM_FRACTION:.0%} of {avail / 1024:.1f} GiB available allowed",
        }
    names = [vehicle(i) for i in range(n)]
    ctx = mp.get_context("spawn")
    with tempfile.TemporaryDirectory() as tmp, router() as endpoint:
        path = Path(tmp) / "scaling.yaml"
        path.write_text(yaml.safe_dump(scenario(n)))
        procs: list[subprocess.Popen[bytes]] = []
        ready, stop, out = ctx.Event(), ctx.Event(), ctx.Queue()
        observer = ctx.Process(target=_observer, args=(endpoint, ready, stop, out))
        observer.start()
        try:
            t0 = time.monotonic()
            for v in names:
                env = client_env(
                    endpoint,
                    {"FIXSTREAM_TERRAIN_NAV_INSTANCE": v, "FIXSTREAM_TERRAIN_NAV_MAP_PATH": MAP},
                    clean=True,
                )
                procs.append(
                    subprocess.Popen([*CLI, "run", "terrain_nav"], env=env, cwd=REPO, stdout=subprocess.DEVNULL)
                )
            _wait_alive(endpoint, names, timeout_s=600)
            startup_s = time.monotonic() - t0
            if not ready.wait(60):
                raise RuntimeError("observer did not start")
            pss = [_pss_mb(p.pid) for p in procs]
            router_pid = _router_pid(endpoint)
            c0 = sum(cpu_s(p.pid) for p in procs)
            r0 = cpu_s(router_pid) if router_pid else float("nan")
            time.sleep(IDLE_S)
            c1 = sum(cpu_s(p.pid) for p in procs)
            r1 = cpu_s(router_pid) if router_pid else float("nan")
            w1 = time.monotonic()
            played = subprocess.run(
                [*CLI, "play", str(path), "--rate", str(RATE), "--no-wait", "--linger", "0.2"],
                env=client_env(endpoint, clean=True),
                cwd=REPO,
                capture_output=True,
                text=True,
                timeout=600 + DURATION_S / max(RATE, 1e-3),
            )
            if played.returncode != 0:
                raise RuntimeError(f"player failed: {played.stderr[-2000:]}")
            player_s = time.monotonic() - w1
            # the services have worked off their queues: their CPU grows no faster than when idle (or 120 s passed)
            idle_cpu_per_s = (c1 - c0) / IDLE_S
            prev, deadline = sum(cpu_s(p.pid) for p in procs), time.monotonic() + 120
            while time.monotonic() < deadline:
                time.sleep(1.0)
                now = sum(cpu_s(p.pid) for p in procs)
                if now - prev <= max(2.0 * idle_cpu_per_s, 0.03):
                    break
                prev = now
            w2 = time.monotonic()
            c2 = sum(cpu_s(p.pid) for p in procs)
            r2 = cpu_s(router_pid) if router_pid else float("nan")
        finally:
            stop.set()
            for p in procs:
                p.terminate()
            for p in procs:
                try:
                    p.wait(timeout=60)
                except subprocess.TimeoutExpired:
                    p.kill()
        inputs, outputs = out.get(timeout=120)
        observer.join(timeout=30)
    idle_cpu_per_s = (c1 - c0) / IDLE_S
    router_idle_per_s = (r1 - r0) / IDLE_S
    busy_s = w2 - w1
    service_cpu = (c2 - c1) - idle_cpu_per_s * busy_s  # above idle
    router_cpu = (r2 - r1) - router_idle_per_s * busy_s
    outputs = [(v, t, stamp, _kind(kind)) for v, t, stamp, kind in outputs]
    if offsets is None:
        offsets = release_offsets_ns(inputs, outputs)
    lat = latencies_ms(inputs, outputs, offsets)
    n_in = len(inputs)
    return {
        "n": n,
        "release_offsets_ns": offsets,
        "startup_s": startup_s,
        "pss_mb_mean": float(np.mean(pss)),
        "inputs": n_in,
        "outputs": len(outputs),
        "offered_msg_per_s": n_in / player_s if player_s > 0 else float("nan"),
        "player_s": player_s,
        "window_s": busy_s,
        "service_cpu_s": c2 - c1,
        "service_cpu_above_idle_s": service_cpu,
        "idle_cpu_per_s": idle_cpu_per_s,
        "router_cpu_s": r2 - r1,
        "cpu_per_msg_us": 1e6 * (c2 - c1) / n_in if n_in else float("nan"),
        "cpu_above_idle_per_msg_us": 1e6 * service_cpu / n_in if n_in else float("nan"),
        "router_idle_cpu_per_s": router_idle_per_s,
        "router_cpu_above_idle_per_msg_us": 1e6 * router_cpu / n_in if n_in else float("nan"),
        "cores_busy": (c2 - c1 + r2 - r1) / busy_s if busy_s > 0 else float("nan"),
        "latency_samples": int(lat.size),
        "latency_p50_ms": float(np.percentile(lat, 50)) if lat.size else float("nan"),
        "latency_p99_ms": float(np.percentile(lat, 99)) if lat.size else float("nan"),
        "latency_max_ms": float(lat.max()) if lat.size else float("nan"),
        "latency_min_ms": float(lat.min()) if lat.size else float("nan"),
    }


def main() -> None:
    results = []
    pss = DEFAULT_PSS_MB
    offsets: dict[str, int] | None = None
    for n in N_LIST:
        print(f"bench_scaling: N = {n} ...", file=sys.stderr, flush=True)
        r = run_n(n, pss, offsets)
        if "pss_mb_mean" in r:
            pss = r["pss_mb_mean"]
            offsets = r["release_offsets_ns"]
        results.append(r)
    rows = []
    for r in results:
        if "skipped" in r:
            rows.append((r["n"], "skipped: " + r["skipped"], *[""] * 9))
            continue
        rows.append(
            (
                r["n"],
                round(r["startup_s"], 1),
                round(r["offered_msg_per_s"]),
                round(r["cpu_above_idle_per_msg_us"]),
                round(r["idle_cpu_per_s"] * 1000 / r["n"], 1),
                round(r["router_cpu_above_idle_per_msg_us"], 1),
                round(r["cores_busy"], 2),
                round(r["latency_p50_ms"], 1),
                round(r["latency_p99_ms"], 1),
                round(r["latency_max_ms"], 1),
                r["latency_samples"],
            )
        )
    emit(
        "scaling",
        [
            "N vehicles",
            "start s",
            "sensor msg/s",
            "services CPU µs/msg",
            "idle CPU ms/s per service",
            "router CPU µs/msg",
            "cores busy",
            "latency p50 ms",
            "latency p99 ms",
            "max ms",
            "outputs timed",
        ],
        rows,
        {
            "estimator": "terrain_nav",
            "rate": RATE,
            "duration_s": DURATION_S,
            "cores": os.cpu_count(),
            "results": results,
            "latency": "output arrival - arrival of the input that released it (stamp >= output stamp + 0.1 s)",
        },
    )


if __name__ == "__main__":
    main()
