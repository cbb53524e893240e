"""What the player puts on the wire, in order: ``(stamp_ns, key, encoding, payload)`` for every event of a run.

The sequence is exactly that of :func:`services.player.timeline.iter_events` encoded with :mod:`shared.codec`
(same keys, same bytes, same order; ``tests/test_player_fast_path.py``), made faster where the simulators allow:

* A simulator with :meth:`~services.player.simulators.ColumnarSimulator.column_streams` (``nav_platform``)
  contributes its streams as columns. All of them are merged at once by a stable sort of their stamps (ties:
  simulator order, then stream order, then row order, which is what the nested ``heapq.merge`` of
  :meth:`Simulation.raw_events` gives) and encoded from a template per stream
  (:class:`~services.player.simulators.columns.RowEncoder`) instead of building, copying and serialising a
  pydantic model per message.
* Every other simulator (and an interactive one driven by an exchange) yields events as before; they are merged
  among themselves with ``heapq.merge`` and the column rows due before each of them are emitted in a run, so an
  interactive simulator is still pulled only after the consumer took its previous event.

``header.source`` is the player's, ``header.seq`` counts per key from 0 in this order.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable, Iterator, Mapping, Sequence
from operator import itemgetter
from typing import NamedTuple, TypeVar

import numpy as np

from shared import codec

from .column_encoding import RowEncoder
from .simulators import ColumnarSimulator, Event, Exchange
from .simulators.columns import CHUNK_ROWS, ColumnStream
from .timeline import Simulation, SimulationError, checked, event_source


class WireEvent(NamedTuple):
    """One message as published: its stamp (for pacing), key, encoding string and msgpack bytes."""

    stamp_ns: int
    key: str
    encoding: str
    payload: bytes


#: consecutive messages as parallel lists (stamps, keys, encodings, payloads): how the player takes them, so that
#: no Python object is made per message besides its bytes
WireChunk = tuple[Sequence[int], Sequence[str], Sequence[str], Sequence[bytes]]
T = TypeVar("T")


class ColumnBatch:
    """The column streams of a run merged by stamp, encoded chunk by chunk on demand (see the module docstring).

    ``header.seq`` per key: the batch numbers its own rows per key at construction; events of other simulators on
    the same keys (allowed, if unusual) shift the later rows through :meth:`take_event_seq`."""

    def __init__(self, streams: list[tuple[int, str, ColumnStream]], duration_ns: int, source: str) -> None:
        """``streams``: (simulator index, simulator id, stream), in simulator order and each simulator's order."""
        streams = [s for s in streams if len(s[2])]
        for _, sim_id, stream in streams:
            _check_stamps(sim_id, stream, duration_ns)
            stream.validate()
        self.key_ids: dict[str, int] = {}
        for _, _, stream in streams:
            self.key_ids.setdefault(stream.key, len(self.key_ids))
        self.keys = [s.key for _, _, s in streams]
        self.encodings = [codec.encoding_of(s.model) for _, _, s in streams]
        stamps = np.concatenate([s.stamps_ns for _, _, s in streams]) if streams else np.zeros(0, np.int64)
        stream_of_row = np.repeat(np.arange(len(streams)), [len(s) for _, _, s in streams])
        order = np.argsort(stamps, kind="stable")  # stable: ties keep simulator, stream and row order
        self.stamps: np.ndarray = stamps[order]
        self.streams: np.ndarray = stream_of_row[order]
        self.sims: np.ndarray = np.array([i for i, _, _ in streams], dtype=np.int64)[self.streams]
        kid_of_stream = np.array([self.key_ids[s.key] for _, _, s in streams], dtype=np.int64)
        self.kids: np.ndarray = kid_of_stream[self.streams]
        # seq within the batch: rank of each row among the batch's rows on its key
        by_key = np.argsort(self.kids, kind="stable")
        starts = np.searchsorted(self.kids[by_key], np.arange(len(self.key_ids)))
        self.seqs = np.empty(len(self.stamps), dtype=np.int64)
        self.seqs[by_key] = np.arange(len(by_key)) - starts[self.kids[by_key]]
        self.encoders = [
            RowEncoder(stream, source, self.seqs[self.streams == j]) for j, (_, _, stream) in enumerate(streams)
        ]

    def __len__(self) -> int:
        return int(self.stamps.size)

    def before(self, stamp_ns: int, sim_index: int) -> int:
        """Number of merged rows that come before an event of simulator ``sim_index`` at ``stamp_ns``."""
        lo = int(np.searchsorted(self.stamps, stamp_ns, side="left"))
        hi = int(np.searchsorted(self.stamps, stamp_ns, side="right"))
        return lo + int(np.searchsorted(self.sims[lo:hi], sim_index, side="left"))

    def key_at(self, row: int) -> tuple[int, int]:
        """(stamp, simulator index) of merged row ``row``: the merge key."""
        return int(self.stamps[row]), int(self.sims[row])

    def take_event_seq(self, key: str) -> int | None:
        """For a message of another simulator on ``key``: the rows of this batch on that key published so far
        (None if the batch has no such key); the later rows' seq move up by one."""
        if key not in self.key_ids:
            return None
        taken = 0
        for k, encoder in zip(self.keys, self.encoders, strict=True):
            if k == key:
                taken += encoder.taken
                encoder.shift(1)
        return taken

    def chunks(self, lo: int, hi: int) -> Iterator[WireChunk]:
        """Merged rows ``lo`` to ``hi - 1``, at most :data:`CHUNK_ROWS` at a time."""
        for a in range(lo, hi, CHUNK_ROWS):
            yield self._chunk(a, min(a + CHUNK_ROWS, hi))

    def _chunk(self, lo: int, hi: int) -> WireChunk:
        streams = self.streams[lo:hi]
        # each stream's rows in this chunk are its next rows, in order: encode them together, then put every row
        # in merged order (by_stream lists the chunk's rows stream by stream, as the encoded lists are concatenated)
        counts = np.bincount(streams, minlength=len(self.encoders))
        encoded: list[bytes] = []
        for s in np.flatnonzero(counts).tolist():
            encoded += self.encoders[s].take(int(counts[s]))
        by_stream = np.argsort(streams, kind="stable")
        place = np.empty_like(by_stream)
        place[by_stream] = np.arange(len(by_stream))
        order = streams.tolist()
        return (
            self.stamps[lo:hi].tolist(),
            _pick(self.keys, order),
            _pick(self.encodings, order),
            _pick(encoded, place.tolist()),
        )


def wire_chunks(sim: Simulation, source: str, exchanges: Mapping[str, Exchange] | None = None) -> Iterator[WireChunk]:
    """Lazily, the run's messages as published by player ``source``, in chunks (``exchanges`` as in
    :meth:`Simulation.raw_events`). An event of a simulator that is not columnar is a chunk of its own, made
    when the previous chunk has been taken."""
    ex = exchanges or {}
    duration_ns = sim.context.duration_ns
    columns: list[tuple[int, str, ColumnStream]] = []
    evented: list[Iterator[tuple[int, int, Event]]] = []
    for i, (sim_id, s) in enumerate(sim.simulators):
        if sim_id not in ex and isinstance(s, ColumnarSimulator):
            columns.extend((i, sim_id, c) for c in s.column_streams())
        else:
            evented.append(_indexed(i, checked(sim_id, event_source(s, ex.get(sim_id)), duration_ns)))
    batch = ColumnBatch(columns, duration_ns, source)
    pos, end = 0, len(batch)
    if evented:
        seq: dict[str, int] = {}
        due = batch.key_at(0) if end else None  # merge key of the next column row
        for stamp, i, ev in heapq.merge(*evented, key=itemgetter(0, 1)):
            if due is not None and due < (stamp, i):
                upto = batch.before(stamp, i)
                yield from batch.chunks(pos, upto)
                pos = upto
                due = batch.key_at(pos) if pos < end else None
            n = seq.get(ev.key, 0)
            seq[ev.key] = n + 1
            rows = batch.take_event_seq(ev.key)
            payload = codec.encode_stamped(ev.msg, source, n + (rows or 0))
            yield [stamp], [ev.key], [codec.encoding_of(type(ev.msg))], [payload]
    yield from batch.chunks(pos, end)


def wire_events(sim: Simulation, source: str, exchanges: Mapping[str, Exchange] | None = None) -> Iterator[WireEvent]:
    """:func:`wire_chunks` one message at a time."""
    for chunk in wire_chunks(sim, source, exchanges):
        yield from map(WireEvent, *chunk)


def _pick(items: Sequence[T], index: list[int]) -> Sequence[T]:
    """``[items[i] for i in index]`` in C (``itemgetter`` of one index gives an item, of several a tuple)."""
    if len(index) == 1:
        return [items[index[0]]]
    return itemgetter(*index)(items) if index else []


def _indexed(index: int, events: Iterable[Event]) -> Iterator[tuple[int, int, Event]]:
    for ev in events:
        yield ev.stamp_ns, index, ev


def _check_stamps(sim_id: str, stream: ColumnStream, duration_ns: int) -> None:
    """What :func:`~services.player.timeline.checked` checks per event, for a whole stream at once."""
    stamps = stream.stamps_ns
    back = np.flatnonzero(np.diff(stamps) < 0)
    if back.size:
        k = int(back[0])
        raise SimulationError(f"simulator {sim_id!r}: stamp {stamps[k + 1]} ns after {stamps[k]} ns on {stream.key}")
    if stamps[0] < 0:
        raise SimulationError(f"simulator {sim_id!r}: stamp {stamps[0]} ns after 0 ns on {stream.key}")
    if stamps[-1] > duration_ns:
        raise SimulationError(f"simulator {sim_id!r}: stamp {stamps[-1]} ns beyond the duration {duration_ns} ns")
