"""Loss accounting from the publishers' own sequence numbers (architecture rule 10: loss is counted where it
happens).

Every publisher stamps ``header.seq`` per key, counting from 0, and Zenoh keeps one publisher's order on a key.
So, per ``(key, source)``, the next message should carry the last seq + 1:

* ``seq == last + 1``: in order.
* ``last + 1 < seq <= last + max_gap``: ``seq - last - 1`` messages were lost in transport (``seq_gap``).
* ``seq > last + max_gap``: a jump no transport loss explains (a publisher that restarted elsewhere in its count,
  or a foreign one): ``seq_jump``, not counted as lost.
* ``seq == last``: a ``duplicate``; ``seq < last``: the publisher started again (``seq_reset``).

The first message of a pair only sets the reference (a subscriber that joins late has lost nothing). The table
is bounded: beyond ``max_pairs`` the least recently seen pair is forgotten (its next message starts afresh).
"""

from __future__ import annotations

from collections import Counter, OrderedDict
from dataclasses import dataclass
from typing import Literal

SeqEvent = Literal["in_order", "first", "seq_gap", "seq_jump", "duplicate", "seq_reset"]


@dataclass(frozen=True)
class SeqCheck:
    event: SeqEvent
    #: messages lost before this one (seq_gap only)
    missing: int = 0
    expected: int = 0


#: the outcomes without figures, built once (the check runs for every sample of every service)
IN_ORDER = SeqCheck("in_order")
_FIRST = SeqCheck("first")


class SeqTracker:
    """Per-(key, source) sequence checks; :attr:`lost` counts transport gaps only."""

    def __init__(self, max_gap: int = 1_000_000, max_pairs: int = 65_536) -> None:
        self.max_gap = max_gap
        self.max_pairs = max_pairs
        self._last: OrderedDict[tuple[str, str], int] = OrderedDict()
        self.lost = 0
        self.events: Counter[str] = Counter()

    def check(self, key: str, source: str, seq: int) -> SeqCheck:
        pair = (key, source)
        last = self._last.get(pair)
        self._last[pair] = seq
        if last is None:
            if len(self._last) > self.max_pairs:
                self._last.popitem(last=False)
            return _FIRST
        self._last.move_to_end(pair)
        expected = last + 1
        if seq == expected:
            return IN_ORDER
        if seq > expected:
            missing = seq - expected
            if missing <= self.max_gap:
                self.lost += missing
                self.events["seq_gap"] += 1
                return SeqCheck("seq_gap", missing, expected)
            self.events["seq_jump"] += 1
            return SeqCheck("seq_jump", 0, expected)
        event: SeqEvent = "duplicate" if seq == last else "seq_reset"
        self.events[event] += 1
        return SeqCheck(event, 0, expected)

    def forget(self, key: str, source: str) -> None:
        """Drop a pair's reference (its publisher announced that it starts again)."""
        self._last.pop((key, source), None)

    def forget_source(self, source: str) -> None:
        """Drop every pair of ``source`` (it announced a new count: a player's start marker)."""
        for pair in [p for p in self._last if p[1] == source]:
            del self._last[pair]

    def as_dict(self) -> dict[str, int]:
        return {"lost": self.lost, **{k: self.events[k] for k in ("seq_gap", "seq_jump", "duplicate", "seq_reset")}}
