"""The bounded queue between Zenoh's delivery threads and a process's own thread.

Zenoh delivers samples on its own threads. Holding such a thread is how a subscriber slows blocking
(``CongestionControl.BLOCK``) publishers down, but holding it too long costs the session (the router closes a
link whose queue a blocking message cannot enter: Zenoh's default is 5 s, ``fixstream router`` waits 60 s), and
Zenoh's own FIFO handler, once full, drops what arrives without a word. So every fixstream process receives
through an :class:`Inbox`: bounded in items and bytes, it holds the delivery thread while it is full for at most
``block_s``, then drops and *counts* (and keeps dropping at once, with no further hold, until it has drained to
half its bounds).
"""

from __future__ import annotations

import queue
import threading
import time
from typing import Any


class Inbox:
    """The inbound queue between Zenoh's delivery threads and the processing thread, bounded in items and bytes.
    Any number of threads may put; one takes.

    ``put`` holds the delivery thread while the queue is full, for at most ``block_s``; then it drops and counts,
    and keeps dropping at once (no further hold) until the queue has drained to half its bounds."""

    def __init__(self, max_items: int, max_bytes: int, block_s: float) -> None:
        self.max_items, self.max_bytes, self.block_s = max_items, max_bytes, block_s
        self._q: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._lock = threading.Lock()  # between the delivery threads (there may be several)
        #: bytes ever admitted (delivery threads, under the lock) and taken (the one processing thread, no lock): the
        #: delivery side may read a stale ``_taken``, which only overstates what is queued
        self._admitted = 0
        self._taken = 0
        self.dropped = 0
        #: of ``dropped``, those released by ``put``'s ``stop`` event rather than after ``block_s``
        self.dropped_at_stop = 0
        self._shedding = False

    @property
    def bytes(self) -> int:
        """Payload bytes queued."""
        return self._admitted - self._taken

    def _admit(self, size: int) -> bool:
        n, b = self._q.qsize(), self._admitted - self._taken
        if self._shedding:
            if n > self.max_items // 2 or b > self.max_bytes // 2:
                return False
            self._shedding = False
        return n < self.max_items and b + size <= self.max_bytes

    def put(self, item: Any, size: int, stop: threading.Event) -> bool:
        """Queue ``item`` (``size`` payload bytes); False if it was dropped (and counted)."""
        with self._lock:  # the common case, inline: not shedding, and room for it
            q = self._q
            if (
                not self._shedding
                and q.qsize() < self.max_items
                and self._admitted - self._taken + size <= self.max_bytes
            ):
                self._admitted += size
                q.put((item, size))
                return True
        return self._put_held(item, size, stop)

    def _put_held(self, item: Any, size: int, stop: threading.Event) -> bool:
        """:meth:`put` when the inbox is full or shedding: hold for at most ``block_s``, then drop and count."""
        deadline: float | None = None
        while True:
            with self._lock:
                if self._admit(size):
                    self._admitted += size
                    self._q.put((item, size))
                    return True
                shedding = self._shedding
            now = time.monotonic()
            if deadline is None:
                deadline = now + self.block_s
            stopped = stop.is_set()
            if shedding or stopped or now >= deadline:
                with self._lock:
                    self._shedding = True
                    self.dropped += 1
                    self.dropped_at_stop += stopped
                return False
            time.sleep(0.001)

    def put_control(self, item: Any) -> None:
        """An item that is never dropped and costs no bytes (the stop sentinel)."""
        self._q.put((item, 0))

    def get(self, timeout: float | None = None) -> Any:
        """The next item (``queue.Empty`` after ``timeout`` s; None: do not wait). One thread only takes from an
        inbox (the process's own): its count of bytes taken needs no lock."""
        item, size = self._q.get(timeout=timeout) if timeout is not None else self._q.get_nowait()
        self._taken += size
        return item

    def qsize(self) -> int:
        return self._q.qsize()

    def take_dropped(self) -> tuple[int, int]:
        """Samples dropped since the last call, and how many of them ``put``'s ``stop`` event released."""
        with self._lock:
            n, self.dropped = self.dropped, 0
            at_stop, self.dropped_at_stop = self.dropped_at_stop, 0
        return n, at_stop
