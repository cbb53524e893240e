"""Integration of the dead-reckoning streams over the epoch grid ([IMPL], digest 000 sections 1.5 and 5.1).

A sample stamped t represents the interval that ends at t (the log's average over its averaging interval):
on a piece (p0, p1] of an epoch interval each signal takes the value of its first sample stamped at or after
p1, or, if none has arrived yet, its last earlier sample (hold). Pieces are cut at every sample stamp inside
the interval, so for 1-Hz samples on the grid each epoch uses exactly the sample stamped at its end.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

from .config import LblNavConfig
from .models import DrInterval

NS = 1_000_000_000


@dataclass
class _Signal:
    stamps: list[int] = field(default_factory=list)
    values: list[tuple[float, ...]] = field(default_factory=list)

    def add(self, stamp_ns: int, value: tuple[float, ...]) -> None:
        i = bisect.bisect_right(self.stamps, stamp_ns)
        self.stamps.insert(i, stamp_ns)
        self.values.insert(i, value)

    def at(self, p_ns: int) -> tuple[float, ...] | None:
        """Backward hold: first sample stamped >= p, else the last one."""
        if not self.stamps:
            return None
        i = bisect.bisect_left(self.stamps, p_ns)
        return self.values[i] if i < len(self.stamps) else self.values[-1]

    def hold(self, p_ns: int) -> tuple[float, ...] | None:
        """Zero-order hold: last sample stamped <= p, else the first one."""
        if not self.stamps:
            return None
        i = bisect.bisect_right(self.stamps, p_ns)
        return self.values[i - 1] if i > 0 else self.values[0]

    def inside(self, a_ns: int, b_ns: int) -> list[int]:
        lo = bisect.bisect_right(self.stamps, a_ns)
        hi = bisect.bisect_left(self.stamps, b_ns)
        return self.stamps[lo:hi]

    def age_s(self, a_ns: int, b_ns: int) -> float:
        """0 if a sample later than a exists, else time from the last sample to b (inf if none)."""
        if not self.stamps:
            return math.inf
        if self.stamps[-1] > a_ns:
            return 0.0
        return (b_ns - self.stamps[-1]) / NS

    def trim(self, b_ns: int) -> None:
        """Keep the samples after b and the last one at or before b."""
        i = bisect.bisect_right(self.stamps, b_ns)
        if i > 1:
            del self.stamps[: i - 1]
            del self.values[: i - 1]


class DrIntegrator:
    """Holds the log, heading and current samples and integrates them per epoch interval."""

    def __init__(self, cfg: LblNavConfig) -> None:
        self.cfg = cfg
        self.speed = _Signal()  # (v_forward, v_starboard) m/s
        self.heading = _Signal()  # (K,) rad
        self.current = _Signal()  # (u_north, u_east) m/s

    def clear(self) -> None:
        self.speed, self.heading, self.current = _Signal(), _Signal(), _Signal()

    def current_speed(self) -> float:
        v = self.current.hold(2**62)
        un, ue = (self.cfg.known_current_north_mps, self.cfg.known_current_east_mps) if v is None else v
        return math.hypot(un, ue)

    def integrate(self, a_ns: int, b_ns: int) -> DrInterval:
        """DR data of the interval (a, b]."""
        cfg = self.cfg
        dt = (b_ns - a_ns) / NS
        gap = max(self.speed.age_s(a_ns, b_ns), self.heading.age_s(a_ns, b_ns))
        if not math.isfinite(gap):
            # no DR at all yet: known current only, velocity unknown
            un, ue = self._current(b_ns)
            return DrInterval(dt, 0.0, 0.0, ue * dt, un * dt, 1.0 + cfg.dr_gap_inflation_per_s * dt, False, math.inf)
        cuts = sorted(set(self.speed.inside(a_ns, b_ns)) | set(self.heading.inside(a_ns, b_ns)))
        cuts.append(b_ns)
        ve = vn = ue_dt = un_dt = 0.0
        p0 = a_ns
        for p1 in cuts:
            if p1 <= p0:
                continue
            d = (p1 - p0) / NS
            sv = self.speed.at(p1)
            sk = self.heading.at(p1)
            assert sv is not None and sk is not None
            vf, vs = sv
            s, c = math.sin(sk[0]), math.cos(sk[0])
            # V^E = V^xi sin K + V^eta cos K, V^N = V^xi cos K - V^eta sin K (V^eta + to starboard)
            ve += (vf * s + vs * c) * d
            vn += (vf * c - vs * s) * d
            un, ue = self._current(p1)
            ue_dt += ue * d
            un_dt += un * d
            p0 = p1
        valid = gap <= cfg.dr_hold_max_s
        scale = 1.0 + cfg.dr_gap_inflation_per_s * gap
        return DrInterval(dt, ve, vn, ue_dt, un_dt, scale, valid, gap)

    def _current(self, p_ns: int) -> tuple[float, float]:
        v = self.current.hold(p_ns)
        if v is None:
            return self.cfg.known_current_north_mps, self.cfg.known_current_east_mps
        return v[0], v[1]

    def trim(self, b_ns: int) -> None:
        self.speed.trim(b_ns)
        self.heading.trim(b_ns)
        self.current.trim(b_ns)
