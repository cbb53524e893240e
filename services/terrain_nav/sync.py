"""Synchronisation of the radio altimeter with the INS (and optional baro) streams (digest §5.1).

Each valid radio-altimeter sample drives processing. The INS position and altitude are interpolated
linearly to t_RA between the bracketing INS samples, each of which (if it has a non-zero weight) must lie
within ``ins_max_gap`` of t_RA; otherwise the RA sample is dropped as unsynchronised. An RA sample that
arrives before the INS sample closing its bracket waits in a short queue. The result is the paper's input
tuple ``(t, x_ins, z_ins, h_ins, h_ra)`` plus the INS ground speed and vertical speed.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from enum import Enum


class Lookup(Enum):
    OK = 0
    WAIT = 1
    DROP = 2


@dataclass(slots=True)
class SyncedSample:
    """One RA sample with the INS quantities interpolated to its time."""

    t: float
    x: float
    z: float
    h_ins: float
    h_ra: float
    v_ground: float
    vh: float | None


class _Stream:
    """The last few samples of one source, for bracketing interpolation."""

    def __init__(self, max_gap_s: float, keep: int = 8) -> None:
        self.max_gap = max_gap_s
        self.samples: deque[tuple[float, tuple[float, ...]]] = deque(maxlen=keep)

    def clear(self) -> None:
        self.samples.clear()

    @property
    def last_t(self) -> float | None:
        return self.samples[-1][0] if self.samples else None

    def add(self, t: float, values: tuple[float, ...]) -> None:
        self.samples.append((t, values))

    def certain_drop(self, t: float) -> bool:
        """True if a sample at t can never be bracketed within max_gap."""
        if not self.samples:
            return True
        if t < self.samples[0][0]:
            return True
        last = self.samples[-1][0]
        return t > last and t - last > self.max_gap

    def lookup(self, t: float) -> tuple[Lookup, tuple[float, ...] | None]:
        """Interpolated values at t, or WAIT (the bracket is not closed yet) or DROP."""
        if self.certain_drop(t):
            return Lookup.DROP, None
        last_t, last_v = self.samples[-1]
        if t > last_t:
            return Lookup.WAIT, None
        if t == last_t:
            return Lookup.OK, last_v
        prev_t, prev_v = self.samples[0]
        for st, sv in self.samples:  # find the bracket a <= t < b
            if st > t:
                b_t, b_v = st, sv
                break
            prev_t, prev_v = st, sv
        else:  # pragma: no cover - t <= last_t guarantees a break
            return Lookup.DROP, None
        if prev_t == t:
            return Lookup.OK, prev_v
        if t - prev_t > self.max_gap or b_t - t > self.max_gap:
            return Lookup.DROP, None
        w = (t - prev_t) / (b_t - prev_t)
        return Lookup.OK, tuple(p + w * (q - p) for p, q in zip(prev_v, b_v, strict=True))


class Synchroniser:
    """Pairs RA samples with interpolated INS (and baro) values; counts what it drops."""

    def __init__(self, ins_max_gap_s: float = 0.2, baro_max_gap_s: float = 0.5, use_baro: bool = False) -> None:
        self.ins = _Stream(ins_max_gap_s)
        self.baro = _Stream(baro_max_gap_s)
        self.use_baro = use_baro
        self.ins_max_gap = ins_max_gap_s
        self.pending: deque[tuple[float, float]] = deque()
        self.dropped = 0

    def reset(self) -> None:
        self.ins.clear()
        self.baro.clear()
        self.pending.clear()

    def _streams(self) -> list[_Stream]:
        return [self.ins, self.baro] if self.use_baro else [self.ins]

    def add_ins(
        self,
        t: float,
        x: float,
        z: float,
        h: float,
        vx: float | None = None,
        vz: float | None = None,
        vh: float | None = None,
    ) -> tuple[list[SyncedSample], bool]:
        """Add an INS sample; returns the RA samples it synchronises and whether it closed an INS gap."""
        last = self.ins.samples[-1] if self.ins.samples else None
        gap = last is not None and t - last[0] > self.ins_max_gap
        if vx is not None and vz is not None:
            v = math.hypot(vx, vz)
        elif last is not None and not gap and t > last[0]:
            v = math.hypot(x - last[1][0], z - last[1][1]) / (t - last[0])
        else:
            v = last[1][3] if (last is not None and not gap) else 0.0
        has_vh = 1.0 if vh is not None else 0.0
        self.ins.add(t, (x, z, h, v, vh if vh is not None else 0.0, has_vh))
        return self._drain(), gap

    def add_baro(self, t: float, h: float) -> list[SyncedSample]:
        self.baro.add(t, (h,))
        return self._drain() if self.use_baro else []

    def would_drop(self, t: float) -> bool:
        """True if an RA sample at t can never be synchronised (checked before it is queued)."""
        return any(s.certain_drop(t) for s in self._streams())

    def add_ra(self, t: float, h_ra: float) -> list[SyncedSample]:
        """Queue a valid RA sample (the caller checks :meth:`would_drop` first) and drain the queue."""
        self.pending.append((t, h_ra))
        return self._drain()

    def _drain(self) -> list[SyncedSample]:
        out: list[SyncedSample] = []
        while self.pending:
            t, h_ra = self.pending[0]
            st, ins = self.ins.lookup(t)
            sb, baro = self.baro.lookup(t) if self.use_baro else (Lookup.OK, None)
            if st == Lookup.DROP or sb == Lookup.DROP:
                self.pending.popleft()
                self.dropped += 1
                continue
            if st == Lookup.WAIT or sb == Lookup.WAIT:
                break
            self.pending.popleft()
            assert ins is not None
            x, z, h, v, vh, has_vh = ins
            if baro is not None:
                h = baro[0]
            out.append(SyncedSample(t, x, z, h, h_ra, v, vh if has_vh >= 1.0 else None))
        return out
