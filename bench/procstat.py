"""CPU time by thread group and for the whole machine, from /proc (Linux), for the benchmarks' breakdowns."""

from __future__ import annotations

import os
from pathlib import Path

#: Zenoh's runtime threads (network I/O, timers, acceptor); any other thread but the main one runs Python callbacks
ZENOH_RUNTIME = ("rx-", "tx-", "net-", "acc-", "app-")

#: what each group of :func:`thread_cpu` holds, for table labels
THREAD_GROUPS = {
    "loop": "its own thread",
    "callback": "the delivery thread (or Zenoh's Python-callback thread)",
    "runtime": "Zenoh's network threads",
}


def thread_cpu(pid: int | None = None) -> dict[str, float]:
    """CPU seconds (user + system) used so far by the threads of process ``pid`` (None: this one), in three groups:
    ``loop`` (the main thread: a fixstream process's own loop), ``callback`` (the other threads, which Zenoh runs
    Python callbacks on) and ``runtime`` (Zenoh's network threads, by name); tick resolution."""
    tck = os.sysconf("SC_CLK_TCK")
    pid = os.getpid() if pid is None else pid
    groups = {"loop": 0.0, "callback": 0.0, "runtime": 0.0}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            comm = (task / "comm").read_text().strip()
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # a thread that ended meanwhile
            continue
        group = "loop" if int(task.name) == pid else "runtime" if comm.startswith(ZENOH_RUNTIME) else "callback"
        groups[group] += (int(fields[11]) + int(fields[12])) / tck
    return groups


def machine_busy_s() -> float:
    """CPU seconds every core of the machine has spent not idle since boot (/proc/stat: all but idle and iowait)."""
    fields = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return (sum(fields[:8]) - fields[3] - fields[4]) / os.sysconf("SC_CLK_TCK")
