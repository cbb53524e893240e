"""``fixstream topics`` and ``fixstream hz`` over a real router (issue 17, item 6), and their rate statistics.

The statistics are checked against closed forms: a stream stamped alternately 40 ms and 60 ms apart has mean
interval 50 ms (20 Hz), min 0.04 s, max 0.06 s and a population standard deviation of exactly 10 ms (every interval
is 10 ms from the mean); intervals kept as integer nanoseconds make these exact up to float rounding.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_support import SOURCE, TestPublisher, depth, finish, start, truth
from hypothesis import given
from hypothesis import strategies as st

from tools.cli.rates import IntervalStats

MS = 1_000_000


# ----- the statistics -------------------------------------------------------------------------------------------
@given(st.lists(st.integers(min_value=1, max_value=10**10), min_size=1, max_size=200))
def test_interval_statistics_equal_numpy_on_the_intervals(intervals_ns: list[int]) -> None:
    stats = IntervalStats()
    t = 10**12
    stats.add(t)
    for d in intervals_ns:
        t += d
        stats.add(t)
    s = stats.summary()
    assert s is not None
    d_s = np.array(intervals_ns, dtype=float) / 1e9
    assert s.messages == len(intervals_ns) + 1 and s.intervals == len(intervals_ns)
    assert s.rate_hz == pytest.approx(1.0 / d_s.mean(), rel=1e-12)
    assert (s.min_s, s.max_s) == (d_s.min(), d_s.max())
    assert s.std_s == pytest.approx(d_s.std(), rel=1e-9, abs=1e-15)  # numpy's std is the population one (ddof=0)


def test_the_window_keeps_the_last_intervals_and_a_backward_time_restarts_it() -> None:
    stats = IntervalStats(window=3)
    for t in (0, 10, 20, 30, 70, 110, 150):  # the last three intervals are 40 ns
        stats.add(t)
    s = stats.summary()
    assert s is not None and s.intervals == 3 and s.min_s == s.max_s == 40e-9 and s.std_s == 0.0
    stats.add(100)  # a stamp going back (one stray message at the end, a new run): a new window starts
    held = stats.summary()  # and, until it holds an interval, the summary is the last window's, not "no rate"
    assert held is not None and s is not None and stats.restarts == 1
    assert (held.messages, held.intervals, held.rate_hz, held.std_s) == (s.messages + 1, 3, s.rate_hz, 0.0)
    stats.add(105)
    s2 = stats.summary()
    assert s2 is not None and s2.intervals == 1 and s2.min_s == 5e-9  # the new window once it has one
    assert IntervalStats().summary() is None and IntervalStats().why_none == "0 message"
    backwards = IntervalStats()
    for t in (30, 20, 10):
        backwards.add(t)
    assert backwards.summary() is None and "each stamped before the one before it" in backwards.why_none
    same = IntervalStats()
    for _ in range(3):
        same.add(7)
    assert same.summary() is None and same.why_none == "3 messages, all at one time"
    with pytest.raises(ValueError):
        IntervalStats(window=0)


# ----- over a router ------------------------------------------------------------------------------------------
@pytest.mark.e2e
def test_hz_on_the_stamp_clock_gives_each_keys_exact_statistics(router: str) -> None:
    a, b = "fixstream/test/hz/a", "fixstream/test/hz/b"
    n_a, n_b = 41, 21
    hz = start(
        "hz",
        "fixstream/test/hz/**",
        "--clock",
        "stamp",
        "--json",
        "--count",
        str(n_a + n_b),
        "--duration",
        "40",
        "--connect",
        router,
    )
    # meanwhile, on keys that carry nothing: exit status 3 (timeout), a one-line reason
    silent_topics = start("topics", "--key", "fixstream/silent/**", "--duration", "0.5", "--connect", router)
    silent_hz = start("hz", "fixstream/silent/**", "--duration", "0.5", "--connect", router)
    pub = TestPublisher(router)
    try:
        pub.wait_for_subscriber(a)
        pub.put_raw(a, b"\xc1", "application/msgpack;fixstream.Truth/1")  # no stamp to read: counted, skipped
        stamps_a = np.cumsum([0] + [40 * MS if i % 2 == 0 else 60 * MS for i in range(n_a - 1)])
        items = [(int(s), a, truth(i, int(s))) for i, s in enumerate(stamps_a)]
        items += [(i * 100 * MS, b, depth(i, i * 100 * MS)) for i in range(n_b)]
        for _, key, msg in sorted(items, key=lambda x: x[0]):
            pub.put(key, msg)
    finally:
        pub.close()
    code, out, err = finish(hz)
    assert code == 0, err
    rows = {r["key"]: r for r in map(json.loads, out.splitlines())}
    assert set(rows) == {a, b}
    ra, rb = rows[a], rows[b]
    assert ra["clock"] == "stamp" and ra["messages"] == n_a and ra["intervals"] == n_a - 1
    assert ra["rate_hz"] == pytest.approx(20.0, rel=1e-12)
    assert (ra["min_s"], ra["max_s"]) == pytest.approx((0.04, 0.06), rel=1e-12)
    assert ra["std_s"] == pytest.approx(0.01, rel=1e-9)
    assert rb["messages"] == n_b and rb["rate_hz"] == pytest.approx(10.0, rel=1e-12) and rb["std_s"] == 0.0
    assert "1 messages without a readable header.stamp_ns skipped" in err
    code, out, err = finish(silent_topics)
    assert code == 3 and err.strip() == "fixstream topics: no message on fixstream/silent/** in 0.5 s" and not out
    code, out, err = finish(silent_hz)
    assert code == 3 and err.strip() == "fixstream hz: no key on fixstream/silent/** had a rate", err


@pytest.mark.e2e
def test_topics_and_hz_on_live_streams(router: str) -> None:
    """Two keys paced at 25 Hz and 10 Hz for 1.6 s against absolute deadlines, with topics and hz (receive clock)
    listening. Receive-time rates on a shared, loaded machine: ±30 % (a late wake-up delays one put, not the mean;
    only a delay of the first or last message moves the span, by ~0.45 s at most for that bound to hold; a wrong unit
    is off by 10^3 or more, counting over the whole 3.5 s window instead of the span of the messages by about -54 %)."""
    a, b = "fixstream/test/live/truth", "fixstream/test/live/depth"
    hz = start("hz", a, "--count", "40", "--duration", "20", "--connect", router)
    pub = TestPublisher(router)
    topics = None
    try:
        pub.wait_for_subscriber(a)  # hz listens (on a only)
        topics = start("topics", "--key", "fixstream/test/live/**", "--duration", "3.5", "--json", "--connect", router)
        pub.wait_for_subscriber(b)  # topics listens
        items = [(i / 25.0, a, truth(i, i * 40 * MS)) for i in range(40)]
        items += [(i / 10.0, b, depth(i, i * 100 * MS)) for i in range(16)]
        pub.paced(sorted(items, key=lambda x: x[0]))
    finally:
        pub.close()
    assert topics is not None
    code, out, err = finish(topics)
    assert code == 0, err
    rows = {r["key"]: r for r in map(json.loads, out.splitlines())}
    assert set(rows) == {a, b}
    assert rows[a]["type"] == "Truth" and rows[b]["type"] == "Depth"
    assert rows[a]["sources"] == [SOURCE] == rows[b]["sources"]
    assert rows[a]["messages"] == 40 and rows[b]["messages"] == 16
    assert rows[a]["rate_hz"] == pytest.approx(25.0, rel=0.3)
    assert rows[b]["rate_hz"] == pytest.approx(10.0, rel=0.3)
    code, out, err = finish(hz)
    assert code == 0, err
    (total,) = [line for line in out.splitlines() if line.startswith("total ")]
    rate = float(total.split()[2])
    assert rate == pytest.approx(25.0, rel=0.3), total
    assert total.startswith(f"total {a}: ") and "window 39" in total
