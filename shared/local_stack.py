"""Where a running local stack (``fixstream up``) says its router is, so that clients attach with no flags.

``fixstream up`` writes ``<state dir>/up-<pid>.json`` (endpoint, compose file, start time) while it runs and
removes it when it ends. A client with no ``--connect`` and no ``FIXSTREAM_ZENOH_CONNECT`` connects to the most
recently started stack whose process is still alive, else to ``tcp/127.0.0.1:7447`` (the port compose publishes).

The state directory is ``$FIXSTREAM_STATE_DIR``, else ``$XDG_RUNTIME_DIR/fixstream``, else
``<tmp>/fixstream-<uid>``: per user, so one user's stack is never another's default.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


@dataclass(frozen=True)
class StackAnnouncement:
    endpoint: str
    pid: int
    compose_file: str
    started_unix_s: float
    path: Path
    #: a secure stack's client identity (ZenohSettings fields tls_root_ca, tls_cert, tls_key); empty when open
    tls: dict[str, str]


def state_dir() -> Path:
    explicit = os.environ.get("FIXSTREAM_STATE_DIR")
    if explicit:
        return Path(explicit)
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime and Path(runtime).is_dir():
        return Path(runtime) / "fixstream"
    return Path(tempfile.gettempdir()) / f"fixstream-{os.getuid()}"


@contextlib.contextmanager
def exclusive() -> Iterator[None]:
    """Hold this user's stack lock (``<state dir>/up.lock``, an exclusive ``flock``): ``fixstream up`` chooses its
    router port and announces it under it, so that two stacks started at once never both choose the free 7447
    (the second then sees the first's announcement). Released when the block ends, or when the process dies."""
    d = state_dir()
    d.mkdir(parents=True, exist_ok=True, mode=0o700)
    with (d / "up.lock").open("a") as f:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)


def announce(endpoint: str, compose_file: str, tls: dict[str, Path] | None = None) -> Path:
    """Write this process's stack announcement (atomically); returns its path for :func:`withdraw`. ``tls``: the
    read-only client identity of a secure stack, which clients with no settings of their own then use."""
    d = state_dir()
    d.mkdir(parents=True, exist_ok=True, mode=0o700)
    path = d / f"up-{os.getpid()}.json"
    tmp = path.with_suffix(".tmp")
    body = {
        "endpoint": endpoint,
        "pid": os.getpid(),
        "compose_file": compose_file,
        "started_unix_s": time.time(),
        "tls": {k: str(v) for k, v in (tls or {}).items()},
    }
    tmp.write_text(json.dumps(body))
    tmp.replace(path)
    return path


def withdraw(path: Path) -> None:
    with contextlib.suppress(FileNotFoundError):
        path.unlink()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def running_stacks() -> list[StackAnnouncement]:
    """Announcements of live stacks, newest first (stale files of dead processes are ignored)."""
    found: list[StackAnnouncement] = []
    d = state_dir()
    if not d.is_dir():
        return found
    for path in d.glob("up-*.json"):
        try:
            body = json.loads(path.read_text())
            ann = StackAnnouncement(
                str(body["endpoint"]),
                int(body["pid"]),
                str(body["compose_file"]),
                float(body["started_unix_s"]),
                path,
                {str(k): str(v) for k, v in dict(body.get("tls") or {}).items()},
            )
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if _alive(ann.pid):
            found.append(ann)
    return sorted(found, key=lambda a: a.started_unix_s, reverse=True)


def default_connect() -> list[str]:
    """The endpoint a client uses when nothing is configured: the newest live local stack, else 7447."""
    stacks = running_stacks()
    return [stacks[0].endpoint] if stacks else [DEFAULT_ENDPOINT]


def default_tls() -> dict[str, str]:
    """The client identity of the newest live local stack if it is secure (else empty)."""
    stacks = running_stacks()
    return stacks[0].tls if stacks else {}
