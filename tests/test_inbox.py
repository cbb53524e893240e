"""The inbox between Zenoh's delivery threads and a process's own thread: bounded in items and bytes, holds a full
put for at most ``block_s``, then drops and counts until it has drained to half its bounds (shared/inbox.py)."""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass, field

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from shared.inbox import Inbox


@dataclass
class _Spec:
    """The inbox as its docstring specifies it, kept apart from the implementation: admits while under both bounds;
    a refused put starts shedding, and while shedding it refuses until both counts are at most half their bounds."""

    max_items: int
    max_bytes: int
    items: list[tuple[int, int]] = field(default_factory=list)
    shedding: bool = False
    dropped: int = 0

    def put(self, item: int, size: int) -> bool:
        n, b = len(self.items), sum(s for _, s in self.items)
        if self.shedding and (n > self.max_items // 2 or b > self.max_bytes // 2):
            ok = False
        else:
            ok = n < self.max_items and b + size <= self.max_bytes
            if ok:
                self.shedding = False
        if ok:
            self.items.append((item, size))
        else:
            self.shedding = True
            self.dropped += 1
        return ok

    def get(self) -> int | None:
        return self.items.pop(0)[0] if self.items else None


#: a size to put, or (negative) take one: about one take in six, so that the bounds are reached and left again
_ops = st.lists(st.integers(-8, 40).map(lambda v: max(v, -1)), max_size=300)


@settings(max_examples=200, deadline=None)
@example(ops=[1, 1, 1, 1, 1, -1, 1, -1, 1, -1, 1], max_items=4, max_bytes=100)  # full, shedding, drained to half
@given(ops=_ops, max_items=st.integers(1, 12), max_bytes=st.integers(1, 120))
def test_the_inbox_admits_drops_and_sheds_as_specified(ops: list[int], max_items: int, max_bytes: int) -> None:
    inbox, spec, stop = Inbox(max_items, max_bytes, block_s=0.0), _Spec(max_items, max_bytes), threading.Event()
    for i, op in enumerate(ops):
        if op < 0:
            expected = spec.get()
            if expected is None:
                with pytest.raises(queue.Empty):
                    inbox.get()
            else:
                assert inbox.get() == expected  # arrival order
        else:
            assert inbox.put(i, op, stop) is spec.put(i, op)
        assert inbox.qsize() == len(spec.items) <= max_items
        assert inbox.bytes == sum(s for _, s in spec.items) <= max_bytes
    assert inbox.take_dropped() == (spec.dropped, 0)  # none released by the stop event: it is never set here
    assert inbox.take_dropped() == (0, 0)  # taken once


def test_a_full_put_waits_for_room_while_the_consumer_takes() -> None:
    inbox, stop = Inbox(2, 1 << 20, block_s=5.0), threading.Event()
    assert inbox.put("a", 1, stop) and inbox.put("b", 1, stop)
    threading.Timer(0.05, inbox.get).start()  # room appears while the third put is held
    assert inbox.put("c", 1, stop)
    assert inbox.take_dropped() == (0, 0)
    assert [inbox.get(), inbox.get()] == ["b", "c"]


def test_a_full_put_drops_and_counts_after_the_hold_then_sheds_at_once() -> None:
    inbox, stop = Inbox(2, 1 << 20, block_s=0.05), threading.Event()
    inbox.put("a", 1, stop)
    inbox.put("b", 1, stop)
    t0 = time.monotonic()
    assert not inbox.put("c", 1, stop)
    assert time.monotonic() - t0 >= 0.05  # held for block_s before the drop
    inbox.get()  # drained to half its bound (1 of 2 items): the next put is admitted again
    assert inbox.put("d", 1, stop)
    assert inbox.take_dropped() == (1, 0)  # held past block_s, not released by the stop


def test_a_stopping_process_does_not_hold_the_delivery_thread() -> None:
    inbox, stop = Inbox(1, 1 << 20, block_s=50.0), threading.Event()
    inbox.put("a", 1, stop)
    stop.set()
    t0 = time.monotonic()
    assert not inbox.put("b", 1, stop)
    assert time.monotonic() - t0 < 5.0  # not the 50 s hold
    assert inbox.take_dropped() == (1, 1)  # counted as released by the stop


def test_control_items_are_never_dropped_and_cost_no_bytes() -> None:
    inbox, stop = Inbox(1, 1 << 16, block_s=0.0), threading.Event()
    inbox.put("a", 100, stop)
    inbox.put_control("stop")
    assert inbox.bytes == 100
    assert [inbox.get(), inbox.get(timeout=0.1)] == ["a", "stop"]
    assert inbox.bytes == 0


def test_concurrent_delivery_threads_never_exceed_the_bounds() -> None:
    """Four delivery threads put as fast as they can while the consumer takes slowly: the queue never holds more than
    its bounds, and every put is either queued (and taken) or counted as dropped."""
    max_items, max_bytes, n, threads = 50, 50 * 10, 2_000, 4
    inbox, stop = Inbox(max_items, max_bytes, block_s=0.0), threading.Event()
    admitted = [0] * threads

    def deliver(t: int) -> None:
        for i in range(n):
            admitted[t] += inbox.put((t, i), 10, stop)

    workers = [threading.Thread(target=deliver, args=(t,)) for t in range(threads)]
    for w in workers:
        w.start()
    taken, deepest, heaviest = 0, 0, 0
    while any(w.is_alive() for w in workers) or inbox.qsize():
        deepest, heaviest = max(deepest, inbox.qsize()), max(heaviest, inbox.bytes)
        try:
            inbox.get(timeout=0.01)
            taken += 1
        except queue.Empty:
            pass
    assert deepest <= max_items and heaviest <= max_bytes
    assert taken == sum(admitted)
    assert taken + inbox.take_dropped()[0] == n * threads
