"""Message-rate statistics as ``ros2 topic hz`` computes them, over a sliding window of arrival (or stamp) times.

For the last ``window`` intervals Δt_i = t_i − t_{i−1} (s) of one key:

* mean rate  f = 1 / mean(Δt)  (Hz), i.e. (n − 1) / (t_last − t_first) over the window's n times;
* min(Δt), max(Δt) and the population standard deviation σ = sqrt(Σ (Δt_i − mean Δt)² / N) (s), N intervals.

Intervals are kept as integer nanoseconds, so a stream stamped on an exact period reports that period exactly.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class RateSummary:
    """The statistics of one key's window (see the module docstring); ``messages`` counts every message seen."""

    messages: int
    intervals: int
    rate_hz: float
    min_s: float
    max_s: float
    std_s: float

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


class IntervalStats:
    """Times of one key (ns, any clock that only moves forward for it) -> :class:`RateSummary` of the last
    ``window`` intervals. A time earlier than the previous one (a stamp going back: a new run, or one stray message)
    starts a new window; until it holds an interval, the summary is the previous window's, so that one stray
    message at the end does not turn 1,200 good intervals into "no rate" (a new user's audit)."""

    def __init__(self, window: int = 10_000) -> None:
        if window < 1:
            raise ValueError("window must be >= 1 interval")
        self.messages = 0
        self.restarts = 0
        self._last: int | None = None
        self._intervals: deque[int] = deque(maxlen=window)
        self._previous: deque[int] = deque()

    def add(self, t_ns: int) -> None:
        self.messages += 1
        if self._last is not None:
            if t_ns < self._last:
                if self._intervals:
                    self._previous = self._intervals
                    self._intervals = deque(maxlen=self._previous.maxlen)
                self.restarts += 1
            else:
                self._intervals.append(t_ns - self._last)
        self._last = t_ns

    def summary(self) -> RateSummary | None:
        """The current window's statistics (the previous window's while the current has no interval); None until
        two times (one interval) have been seen, or when every interval is 0 (no rate: :attr:`why_none`)."""
        window = self._intervals or self._previous
        n = len(window)
        if n == 0:
            return None
        total = sum(window)
        if total == 0:
            return None
        mean_ns = total / n
        var_ns2 = sum((d - mean_ns) ** 2 for d in window) / n
        return RateSummary(
            messages=self.messages,
            intervals=n,
            rate_hz=NS_PER_S / mean_ns,
            min_s=min(window) / NS_PER_S,
            max_s=max(window) / NS_PER_S,
            std_s=math.sqrt(var_ns2) / NS_PER_S,
        )

    @property
    def why_none(self) -> str:
        """Why :meth:`summary` is None, in words."""
        if self.messages < 2:
            return f"{self.messages} message"
        if not (self._intervals or self._previous):
            return f"{self.messages} messages, each stamped before the one before it"
        return f"{self.messages} messages, all at one time"
