"""What ``echo``, ``hz`` and ``topics`` share: subscribe to a key expression and hand over its samples in order.

Zenoh calls the subscriber's callback on its own threads; :class:`Listener` puts each sample (key, payload,
encoding, receive time) on a queue that the command's main thread reads with :meth:`Listener.samples`, until a
deadline, Ctrl-C or SIGTERM (both end the command normally: these commands run until they are stopped).
"""

from __future__ import annotations

import argparse
import queue
import signal
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from types import TracebackType
from typing import Any


@dataclass(frozen=True)
class Sample:
    key: str
    payload: bytes
    encoding: str
    #: receive time, ns on the monotonic clock (intervals only)
    rx_ns: int


class Listener:
    """A client session subscribed to ``key_expr`` (settings from the command's ``--connect`` etc.)."""

    def __init__(self, args: argparse.Namespace, key_expr: str) -> None:
        from shared.session import open_session

        from .common import zenoh_settings_from

        self.stopped = threading.Event()
        self._queue: queue.Queue[Sample] = queue.Queue()
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: self.stopped.set())
        self.session = open_session(zenoh_settings_from(args))
        self._sub = self.session.declare_subscriber(key_expr, self._on_sample)

    def _on_sample(self, s: Any) -> None:
        self._queue.put(Sample(str(s.key_expr), s.payload.to_bytes(), str(s.encoding), time.monotonic_ns()))

    def samples(self, duration_s: float = 0.0) -> Iterator[Sample]:
        """Samples in arrival order until ``duration_s`` has passed (0: no limit) or the command is stopped."""
        deadline = time.monotonic() + duration_s if duration_s > 0 else float("inf")
        while not self.stopped.is_set():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return
            try:
                yield self._queue.get(timeout=min(0.1, remaining))
            except queue.Empty:
                continue

    def close(self) -> None:
        self._sub.undeclare()
        self.session.close()

    def __enter__(self) -> Listener:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def schema_of(encoding: str) -> str:
    """The model name in a fixstream encoding (``application/msgpack;fixstream.Truth/1`` -> ``Truth``), else the
    encoding itself (a foreign publisher's)."""
    from shared import codec

    prefix = codec.MEDIA_TYPE + ";fixstream."
    return encoding[len(prefix) :].split("/", 1)[0] if encoding.startswith(prefix) else encoding or "(none)"
