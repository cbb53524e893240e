"""Start and loss-of-lock recovery from snapshot fixes (digest §4.4 step 8, §4.5, §7.4).

After K consecutive gated-out cycles, each rejected cycle's snapshot Gauss-Newton fix is carried to the
newest epoch with the DR displacement (if the same beacon's late arrival explains every one of them at the
current estimate, ``k_same_outlier`` cycles are required instead: with M = 2 a repeated late arrival and a
position error along the other hyperbola look alike for a few cycles); if the K fixes agree within
``consistency_m + drift_mps * span`` (span: the time between the oldest and the newest of them; ``drift_mps``
bounds the DR velocity error, so a biased DR over a long run of rejected cycles cannot block the re-seed; 0 gives
the digest's fixed 5 m) and the newest lies within ``max_distance_m`` of the current estimate, the cloud is
re-seeded as N(X_snap, scale * P_CRLB + extra * I). A rejected cycle with no snapshot fix (a partial M = 1 cycle, or
no Gauss-Newton solution) counts towards K but neither adds a fix nor breaks the run, unless ``strict_chain``
(the K fixes must then come from K consecutive cycles). The same rule (without the distance check) starts a
filter that has no start position.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from shared.filters.covariance import symmetrize

from .geometry import F64


@dataclass(frozen=True)
class Snapshot:
    """A snapshot fix of one cycle with the cumulative DR position at its epoch."""

    p: F64  # (2,) m
    P_crlb: F64  # (2, 2) m^2
    dr_xy: F64  # (2,) cumulative DR at the epoch, m
    t_s: float = 0.0  # epoch of the fix, s


@dataclass(frozen=True)
class Proposal:
    mean: F64
    cov: F64
    spread_m: float


class Reinitialiser:
    """Keeps the snapshot fixes of the last K rejected cycles and proposes a re-seed."""

    def __init__(
        self,
        k: int,
        consistency_m: float,
        max_distance_m: float,
        crlb_scale: float,
        extra_var_m2: float,
        k_same_outlier: int | None = None,
        drift_mps: float = 0.0,
        strict_chain: bool = True,
    ) -> None:
        self.k = k
        self.k_same_outlier = max(k, k_same_outlier or k)
        self.consistency_m = consistency_m
        self.max_distance_m = max_distance_m
        self.crlb_scale = crlb_scale
        self.extra_var_m2 = extra_var_m2
        self.drift_mps = drift_mps
        self.strict_chain = strict_chain
        self.consecutive = 0
        self._snaps: deque[Snapshot | None] = deque(maxlen=k)
        self._tags: deque[str | None] = deque(maxlen=k)

    def clear(self) -> None:
        self.consecutive = 0
        self._snaps.clear()
        self._tags.clear()

    def record(self, snap: Snapshot | None, late_arrival: str | None = None) -> None:
        """Record a cycle the filter could not use whole: its snapshot fix (None if none could be computed)
        and, if one late arrival explains it at the current estimate, that arrival's beacon id."""
        self.consecutive += 1
        if snap is None and not self.strict_chain:
            return
        self._snaps.append(snap)
        self._tags.append(late_arrival)

    def propose(self, estimate: F64 | None) -> Proposal | None:
        """A re-seed if the last K rejected cycles gave K consistent snapshot fixes, else None."""
        if self.consecutive < self.k or len(self._snaps) < self.k:
            return None
        tags = set(self._tags)
        if len(tags) == 1 and None not in tags and self.consecutive < self.k_same_outlier:
            return None  # the same beacon late K times explains it at x_hat as well: wait longer
        snaps = list(self._snaps)
        if any(s is None for s in snaps):
            return None
        newest = snaps[-1]
        assert newest is not None
        carried = np.array([s.p + (newest.dr_xy - s.dr_xy) for s in snaps if s is not None])
        diff = carried[:, None, :] - carried[None, :, :]
        spread = float(np.sqrt((diff**2).sum(axis=2)).max())
        span_s = max(s.t_s for s in snaps if s is not None) - min(s.t_s for s in snaps if s is not None)
        if spread > self.consistency_m + self.drift_mps * span_s:
            return None
        if estimate is not None and float(np.hypot(*(newest.p - estimate))) > self.max_distance_m:
            return None
        cov = self.crlb_scale * newest.P_crlb + self.extra_var_m2 * np.eye(2)
        return Proposal(mean=newest.p.copy(), cov=symmetrize(cov), spread_m=spread)
