"""Shared fixtures: a real Zenoh router on a free loopback port, and example messages."""

from __future__ import annotations

import atexit
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests"))
# where `fixstream up` announces its router (shared.local_stack): the tests' own, never a user's running stack,
# removed when the test process ends (one per run used to be left behind in /tmp)
if "FIXSTREAM_STATE_DIR" not in os.environ:
    os.environ["FIXSTREAM_STATE_DIR"] = _STATE_DIR = tempfile.mkdtemp(prefix="fixstream-test-state-")
    atexit.register(shutil.rmtree, _STATE_DIR, ignore_errors=True)


def fixstream_cmd(*args: str) -> list[str]:
    """The installed console script run with this interpreter's environment."""
    return [sys.executable, "-m", "tools.cli.main", *args]


@contextmanager
def running_router(*connect: str) -> Iterator[str]:
    """A ``fixstream router`` subprocess on a free loopback port, meshed with the routers at ``connect``; yields its
    endpoint. Its log goes to a temporary file (a pipe nobody reads could fill and stall it)."""
    from shared.session import free_tcp_port

    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    args = ["router", "--listen", endpoint, *(a for c in connect for a in ("--connect", c))]
    with tempfile.TemporaryFile("w+") as log:
        proc = subprocess.Popen(fixstream_cmd(*args), stdout=subprocess.PIPE, stderr=log, text=True, cwd=REPO)
        assert proc.stdout is not None
        line = proc.stdout.readline()
        if "listening" not in line:
            log.seek(0)
            raise AssertionError(f"router did not start: {line!r} {log.read()[-3000:]}")
        try:
            yield endpoint
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()


@pytest.fixture()
def router() -> Iterator[str]:
    """A ``fixstream router`` subprocess on a free loopback port; yields its endpoint."""
    with running_router() as endpoint:
        yield endpoint


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


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Tests that need a container engine (the ``images`` fixture) or node fail where it is missing, so that a green
    run means they ran; a machine without one leaves them out explicitly: ``FIXSTREAM_CONTAINER_TEST=off``,
    ``FIXSTREAM_NODE_TEST=off`` (reported as deselected)."""
    off_containers = os.environ.get("FIXSTREAM_CONTAINER_TEST", "").lower() == "off"
    off_node = os.environ.get("FIXSTREAM_NODE_TEST", "").lower() == "off"
    if not (off_containers or off_node):
        return
    keep, drop = [], []
    for item in items:
        needs_engine = "images" in getattr(item, "fixturenames", ())
        needs_node = item.get_closest_marker("node") is not None
        (drop if (off_containers and needs_engine) or (off_node and needs_node) else keep).append(item)
    if drop:
        config.hook.pytest_deselected(items=drop)
        items[:] = keep
