"""What the service benchmarks share: one service process on a real router, the real player flat out, the clock.

A benchmark starts a router (:func:`bench.stack.router`), the service (:func:`start_service`, configured by its
``FIXSTREAM_*`` environment from :func:`client_env`), and either times the service's outputs while the player
publishes (:func:`play_timed`: wall time and the service's CPU time from ``/proc`` between the ``warm``-th and the
last output) or runs the player itself (:func:`play`) and reads the service's status (:func:`service_status`).
The offline comparison (the same messages through ``run_offline`` in this process) stays with each benchmark.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from shared import keys
from shared.session import open_session
from shared.settings import ZenohSettings

from .stack import REPO

#: ``fixstream`` as this interpreter runs it, logging warnings only
CLI = [sys.executable, "-m", "tools.cli.main", "--log-level", "WARNING"]
#: the player's last log line: messages published and its own time
PLAYER_LINE = re.compile(r"published (\d+) messages on \d+ keys in ([0-9.]+) s")
_TICK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User + system CPU time of a process (all its threads), s."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _TICK


def client_env(endpoint: str, settings: Mapping[str, str] | None = None, clean: bool = False) -> dict[str, str]:
    """This process's environment (without its ``FIXSTREAM_*`` settings if ``clean``) as a client of the router at
    ``endpoint``, logging warnings only, plus ``settings`` (``FIXSTREAM_<SERVICE>_<FIELD>`` = value)."""
    env = {k: v for k, v in os.environ.items() if not (clean and k.startswith("FIXSTREAM_"))}
    env.update(
        {"FIXSTREAM_ZENOH_MODE": "client", "FIXSTREAM_ZENOH_CONNECT": endpoint, "FIXSTREAM_LOG_LEVEL": "WARNING"}
    )
    env.update(settings or {})
    return env


def start_service(name: str, env: dict[str, str], quiet: bool = False) -> subprocess.Popen[bytes]:
    """``fixstream run <name>`` with ``env``; ``quiet``: its output discarded."""
    out = subprocess.DEVNULL if quiet else None
    return subprocess.Popen([*CLI, "run", name], env=env, cwd=REPO, stdout=out, stderr=out)


def stop(*procs: subprocess.Popen[bytes] | None) -> None:
    """SIGTERM the processes (a service drains and exits) and wait for them."""
    for proc in procs:
        if proc is not None:
            proc.terminate()
            proc.wait(timeout=30)


@dataclass(frozen=True)
class Played:
    """One ``fixstream play --rate 0``: its wall time seen from here and the time it reports itself (NaN if not)."""

    wall_s: float
    player_s: float


def play(path: Path, env: dict[str, str], *args: str, timeout_s: float = 600) -> Played:
    """``fixstream play <path> --rate 0 <args>`` to the end; fails if the player does."""
    t0 = time.perf_counter()
    done = subprocess.run(
        [*CLI, "play", str(path), "--rate", "0", *args],
        env=env,
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"player failed: {done.stderr[-2000:]}")
    found = PLAYER_LINE.search(done.stdout + done.stderr)
    return Played(wall, float(found.group(2)) if found else float("nan"))


def service_status(session: zenoh.Session, name: str, instance: str) -> dict[str, Any]:
    """The service's status (its queryable), or {} if it did not answer."""
    for reply in session.get(keys.status(name, instance), timeout=5.0):
        if reply.ok is not None:
            return dict(json.loads(reply.ok.payload.to_bytes()))
    return {}


@dataclass(frozen=True)
class Window:
    """From the ``warm``-th output to the last: wall time and the service's CPU time, s; and the player's wall time."""

    wall_s: float
    cpu_s: float
    player_wall_s: float


def play_timed(
    endpoint: str,
    path: Path,
    key: str,
    service_pid: int,
    warm: int,
    total: int,
    timeout_s: float = 300,
    seed: int | None = None,
) -> Window:
    """Play the scenario once (``--seed`` if given) while counting the outputs on ``key``: the clock and the
    service's CPU time are read at output number ``warm`` (1-based) and at number ``total``."""
    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    count = 0
    marks: dict[str, tuple[float, float]] = {}
    done = threading.Event()
    lock = threading.Lock()

    def on_output(_sample: object) -> None:
        nonlocal count
        with lock:
            count += 1
            n = count
        if n == warm:
            marks["warm"] = (time.perf_counter(), cpu_s(service_pid))
        if n == total:
            marks["end"] = (time.perf_counter(), cpu_s(service_pid))
            done.set()

    sub = session.declare_subscriber(key, on_output)
    try:
        played = play(path, client_env(endpoint), *([] if seed is None else ["--seed", str(seed)]))
        if not done.wait(timeout=timeout_s):
            raise RuntimeError(f"only {count} of {total} outputs on {key} arrived")
    finally:
        sub.undeclare()
        session.close()
    (tw, cw), (te, ce) = marks["warm"], marks["end"]
    return Window(te - tw, ce - cw, played.wall_s)
