"""Shared fixtures: a real Zenoh router on a free loopback port, and example messages."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests"))
# where `fixstream up` announces its router (shared.local_stack): the tests' own, never a user's running stack
os.environ.setdefault("FIXSTREAM_STATE_DIR", tempfile.mkdtemp(prefix="fixstream-test-state-"))


def fixstream_cmd(*args: str) -> list[str]:
    """The installed console script run with this interpreter's environment."""
    return [sys.executable, "-m", "tools.cli.main", *args]


@pytest.fixture()
def router() -> Iterator[str]:
    """A ``fixstream router`` subprocess on a free loopback port; yields its endpoint."""
    from shared.session import free_tcp_port

    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    proc = subprocess.Popen(
        fixstream_cmd("router", "--listen", endpoint),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert "listening" in line, f"router did not start: {line!r} {proc.stderr.read() if proc.stderr else ''}"
    try:
        yield endpoint
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def service_env(endpoint: str, **extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env.update({"FIXSTREAM_ZENOH_MODE": "client", "FIXSTREAM_ZENOH_CONNECT": endpoint})
    env.update(extra)
    return env


def wait_until(predicate, timeout: float = 10.0, interval: float = 0.05) -> bool:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval)
    return bool(predicate())
