"""Pace a stream by its own time stamps on the wall clock (``rate`` times real time; 0 = no pacing)."""

from __future__ import annotations

import threading
import time

from .simulators import NS_PER_S

#: one wait of the pacer at most, s (threading.TIMEOUT_MAX is about 9.2e9 s; a day is plenty)
_LONGEST_WAIT_S = 86_400.0


class Pacer:
    """Sleeps so that data stamp ``s`` goes out ``(s - s_first) / rate`` seconds after the first one."""

    def __init__(self, rate: float, stop: threading.Event | None = None) -> None:
        if rate < 0:
            raise ValueError("rate must be >= 0 (0: as fast as possible)")
        self.rate = rate
        self.stop = stop or threading.Event()
        self._origin_stamp: int | None = None
        self._origin_wall = 0.0

    def wait(self, stamp_ns: int) -> bool:
        """Block until ``stamp_ns`` is due. Returns False if stopped meanwhile."""
        if self.rate == 0:
            return not self.stop.is_set()
        if self._origin_stamp is None:
            self._origin_stamp = stamp_ns
            self._origin_wall = time.monotonic()
        due = self._origin_wall + (stamp_ns - self._origin_stamp) / NS_PER_S / self.rate
        while (delay := due - time.monotonic()) > 0:  # in slices: a slow rate's wait can exceed the OS's longest
            if self.stop.wait(min(delay, _LONGEST_WAIT_S)):
                return False
        return not self.stop.is_set()
