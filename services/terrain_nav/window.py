"""The segmented sliding window of squared-residual arrays (digest §2.3, §2.9 S3, §2.11 ``window_push``).

Incoming e^2 arrays are summed into segments of N_s *ticks* (cell measurements); only each segment's sum
array is stored, with its count of accumulated arrays (an excluded first-after-gap residual is a tick
without an array, so a segment may hold fewer than N_s arrays). Segments leave the window whole: the
oldest closed segment is popped while ``N_valid - count(oldest) >= N_max`` (exit condition [D]), its sum
subtracted from the running total F, and as many measurements as it has ticks leave the measurement
queue, which therefore always holds exactly the measurements of the window.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

from .geometry import F64

T = TypeVar("T")


@dataclass
class Segment:
    """A closed segment: the sum of its e^2 arrays, how many arrays and how many ticks it holds."""

    total: F64
    n: int
    ticks: int


class SegmentedWindow(Generic[T]):
    """Running windowed sum F of e^2 arrays with N_s-fold reduced storage."""

    def __init__(self, shape: tuple[int, ...], N_s: int, N_max: int, recompute_segments: int = 50) -> None:
        self.shape = shape
        self.N_s = N_s
        self.N_max = N_max
        self.recompute_segments = recompute_segments
        self.F: F64 = np.zeros(shape)
        self.seg_open: F64 = np.zeros(shape)
        self.seg_n = 0
        self.seg_ticks = 0
        self.segq: deque[Segment] = deque()
        self.measq: deque[T] = deque()
        self.N_valid = 0
        self._closed_since_recompute = 0

    def reset(self) -> None:
        """Empty the window (F, segments, measurement queue, N_valid)."""
        self.F.fill(0.0)
        self.seg_open.fill(0.0)
        self.seg_n = 0
        self.seg_ticks = 0
        self.segq.clear()
        self.measq.clear()
        self.N_valid = 0
        self._closed_since_recompute = 0

    def push(self, e2: F64 | None, meas: T) -> None:
        """Add one tick: the measurement and its e^2 array (``None`` for an excluded residual)."""
        if e2 is not None:
            self.F += e2
            self.seg_open += e2
            self.seg_n += 1
            self.N_valid += 1
        self.seg_ticks += 1
        self.measq.append(meas)
        if self.seg_ticks == self.N_s:  # close the segment (it may hold fewer than N_s arrays) [P]
            self.segq.append(Segment(self.seg_open.copy(), self.seg_n, self.seg_ticks))
            self.seg_open.fill(0.0)
            self.seg_n = 0
            self.seg_ticks = 0
            self._closed_since_recompute += 1
        while self.segq and self.N_valid - self.segq[0].n >= self.N_max:  # exit condition [D]
            seg = self.segq.popleft()
            self.F -= seg.total
            self.N_valid -= seg.n
            for _ in range(seg.ticks):
                self.measq.popleft()
        if self._closed_since_recompute >= self.recompute_segments:
            self.recompute()

    def recompute(self) -> None:
        """F = open segment + sum of closed segments (cancels add/subtract round-off)."""
        F = self.seg_open.copy()
        for seg in self.segq:
            F += seg.total
        self.F[...] = F
        self._closed_since_recompute = 0

    @property
    def ticks(self) -> int:
        """Measurements currently in the window (= length of the measurement queue)."""
        return self.seg_ticks + sum(s.ticks for s in self.segq)

    def stored_arrays(self) -> int:
        """Per-hypothesis e^2 arrays stored in the window: closed segment sums plus the open segment."""
        return len(self.segq) + 1

    def memory_bytes(self) -> int:
        """Bytes of the window's per-hypothesis arrays: the stored segments plus the running sum F."""
        return (self.stored_arrays() + 1) * self.F.nbytes
