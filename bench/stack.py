"""A real router subprocess for benchmarks (same command the stack runs)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from shared.session import free_tcp_port

REPO = Path(__file__).resolve().parent.parent


def start_router(endpoint: str) -> subprocess.Popen[str]:
    """``fixstream router --listen endpoint``, returned once it listens."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "tools.cli.main", "router", "--listen", endpoint],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        cwd=REPO,
    )
    assert proc.stdout is not None
    if "listening" not in proc.stdout.readline():
        proc.kill()
        raise RuntimeError("router did not start")
    return proc


@contextmanager
def router() -> Iterator[str]:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    proc = start_router(endpoint)
    try:
        yield endpoint
    finally:
        proc.terminate()
        proc.wait(timeout=10)
