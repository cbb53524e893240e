"""The recorder's loss accounting of a player's run, as a property (Hypothesis): whatever is lost, and wherever in
a stream (its head, its middle, its tail, or all of it), what the player's end marker counts is what arrived plus
what the recorder counted as lost (``lost``: gaps the seq check sees, and a stream's head after a start marker it
saw) plus what it counted at the run's end (``lost_at_end``). Nothing is counted twice, and nothing is counted
for a player whose start marker the recorder never saw (it joined late: what came before was not lost).

Offline: the recorder's ``on_sample`` path with real MCAP files, no Zenoh (the scheduling of the end check, one
second after the marker once the inbox is empty, is the end-to-end tests' business: tests/test_recorder.py and
the container crash test)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any, cast

from hypothesis import given, settings
from hypothesis import strategies as st
from samples import EXAMPLES

from schemas import Header, ScenarioMarker
from services.recorder.service import RecorderService
from services.recorder.settings import RecorderSettings
from shared import codec, keys

SOURCE = "player/acct"
DEPTH = codec.encoding_of(type(EXAMPLES["Depth"]))
MARKERS = keys.scenario("acct")

#: per key: how many the player published (0-12) and which seqs the transport lost
streams = st.lists(st.tuples(st.integers(0, 12), st.sets(st.integers(0, 11))), min_size=1, max_size=5)


def _marker(event: str, seq: int, published: dict[str, int], source: str = SOURCE) -> bytes:
    header = Header(stamp_ns=1 + seq, frame_id="scenario", source=source, seq=seq)
    return codec.encode(ScenarioMarker(header=header, event=event, scenario="acct", seed=1, published=published))


def _recorder(out_dir: Path) -> RecorderService:
    rec = RecorderService(RecorderSettings(out_dir=out_dir, instance="acct"))
    rec._control = cast(Any, object())  # a session stand-in: the start marker's status query fails quietly
    return rec


def _play(rec: RecorderService, spec: list[tuple[int, set[int]]], start: bool = True) -> tuple[int, int]:
    """Feed the player's run (its start marker if ``start``, then the keys' surviving messages round-robin, each key
    in order, then its end marker); returns (published, arrived)."""
    encoding = codec.encoding_of(ScenarioMarker)
    if start:
        rec.on_sample(MARKERS, _marker("start", 0, {}), encoding)
    queues = [
        [(f"fixstream/sensor/a/depth/k{i}", s) for s in range(n) if s not in lost] for i, (n, lost) in enumerate(spec)
    ]
    while any(queues):
        for q in queues:
            if q:
                key, seq = q.pop(0)
                rec.on_sample(key, codec.encode_stamped(EXAMPLES["Depth"], SOURCE, seq), DEPTH)
    published = {f"fixstream/sensor/a/depth/k{i}": n for i, (n, _) in enumerate(spec)}
    rec.on_sample(MARKERS, _marker("end", 1, published), encoding)
    while rec._ends:  # what _housekeeping does once the check is due
        rec._check_end(*rec._ends.popleft()[:2])
    arrived = sum(n - len(lost & set(range(n))) for n, lost in spec)
    return sum(published.values()), arrived


@settings(max_examples=60, deadline=None)
@given(spec=streams)
def test_every_message_a_player_counted_arrived_or_is_counted_lost_once(spec: list[tuple[int, set[int]]]) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        rec = _recorder(Path(tmp))
        try:
            published, arrived = _play(rec, spec)
            assert rec.seq.lost + rec.lost_at_end == published - arrived
            assert rec.counters.accepted == arrived + 2  # and every message that came is recorded (the markers too)
        finally:
            rec.on_stop()


@settings(max_examples=20, deadline=None)
@given(spec=streams)
def test_a_run_whose_start_the_recorder_missed_is_not_judged(spec: list[tuple[int, set[int]]]) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        rec = _recorder(Path(tmp))
        try:
            _play(rec, spec, start=False)
            assert rec.lost_at_end == 0  # the end marker of a run it joined late is not held against the transport
            # what the seq check sees between two arrivals is lost whoever started when
            gaps = sum(max(kept) - min(kept) + 1 - len(kept) for n, lost in spec if (kept := set(range(n)) - lost))
            assert rec.seq.lost == gaps
        finally:
            rec.on_stop()
