"""A stream held as columns: one array per message field, one row per sample (the fast path of the player).

A simulator whose streams are sampled on a grid (``nav_platform``: truth and every navigation sensor) computes
each field for every sample at once with numpy. :class:`ColumnStream` keeps them that way; row ``i`` is the message

    model(header=Header(stamp_ns=stamps_ns[i], frame_id=frame_id), **{f: columns[f][i]}, **constants)

where a column named ``"parent.child"`` is the entry ``child`` of the dict field ``parent`` (``Truth.extra``) and a
column of shape ``(n, k)`` is a list field of ``k`` components (``Truth.position_m``).

Two readers, one definition:

* :meth:`ColumnStream.events` builds each row's message through the pydantic model (validated, as every simulator
  does): the Monte-Carlo runner, the tests and ``scenario_events`` read that.
* the player (:mod:`services.player.column_encoding`) writes the bytes ``codec.encode_stamped(message(i), source,
  seq)`` straight from the columns, many rows at a time, without building the messages. What the model would
  check is checked once per stream by :meth:`ColumnStream.validate`, see there.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from schemas import Header, Message
from shared.events import Event

#: rows turned into Python objects at a time (bounded memory for long streams)
CHUNK_ROWS = 4096


@dataclass(frozen=True)
class ColumnStream:
    """The messages of one key as columns (see the module docstring)."""

    key: str
    model: type[Message]
    frame_id: str
    #: (n,) int64, non-decreasing: the event stamps, equal to each header's ``stamp_ns``
    stamps_ns: np.ndarray
    #: field name (or ``"parent.child"``) -> (n,) or (n, k) array, in the order the fields are given
    columns: dict[str, np.ndarray]
    #: fields with the same value in every row
    constants: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.stamps_ns.size)

    def field_values(self, lo: int, hi: int) -> tuple[list[str], list[list[Any]]]:
        """Top-level field names and, per field, the Python values of rows ``lo`` to ``hi - 1``.

        ``ndarray.tolist`` gives Python floats (lists for (n, k) columns); the ``"parent.child"`` columns become one
        dict per row, in column order."""
        names: list[str] = []
        values: list[list[Any]] = []
        nested: dict[str, list[tuple[str, np.ndarray]]] = {}
        for name, col in self.columns.items():
            parent, dot, child = name.partition(".")
            if dot:
                if parent not in nested:
                    nested[parent] = []
                    names.append(parent)
                    values.append([])  # filled below, keeping the field's place
                nested[parent].append((child, col))
            else:
                names.append(name)
                values.append(col[lo:hi].tolist())
        for parent, children in nested.items():
            keys = [c for c, _ in children]
            rows = zip(*(col[lo:hi].tolist() for _, col in children), strict=True)
            values[names.index(parent)] = [dict(zip(keys, r, strict=True)) for r in rows]
        return names, values

    def message(self, i: int) -> Message:
        """Row ``i`` as its validated model."""
        names, values = self.field_values(i, i + 1)
        stamp = int(self.stamps_ns[i])
        fields = {n: v[0] for n, v in zip(names, values, strict=True)}
        return self.model(header=Header(stamp_ns=stamp, frame_id=self.frame_id), **fields, **self.constants)

    def events(self) -> Iterator[Event]:
        """Every row as an :class:`Event` whose message is built (and validated) through the model."""
        model, frame_id, key, constants = self.model, self.frame_id, self.key, self.constants
        for lo in range(0, len(self), CHUNK_ROWS):
            hi = min(lo + CHUNK_ROWS, len(self))
            names, values = self.field_values(lo, hi)
            for stamp, *row in zip(self.stamps_ns[lo:hi].tolist(), *values, strict=True):
                fields = dict(zip(names, row, strict=True))
                yield Event(stamp, key, model(header=Header(stamp_ns=stamp, frame_id=frame_id), **fields, **constants))

    def validate(self) -> None:
        """Raise what building a message would raise if any row is not a valid message; cheap.

        Only the rows that could fail are built through the model: those holding each column's (and each
        component's) smallest and largest value, every row with a non-finite value, and the first and last rows.
        That covers every constraint that is an interval on a single value (``ge``/``gt``/``le``/``lt``, finite
        floats: the constraints of the models a column stream carries, ``Truth`` and the navigation sensors):
        if the extremes are inside the interval, so is every value between them. A model with constraints across
        fields or rows must not be given as columns (its simulator yields events).
        """
        n = len(self)
        if n == 0:
            return
        rows = {0, n - 1}
        for col in self.columns.values():
            flat = col.reshape(n, -1)
            finite = np.isfinite(flat)
            if not finite.all():
                rows.update(np.flatnonzero(~finite.all(axis=1))[:1].tolist())
                continue
            rows.update(np.argmin(flat, axis=0).tolist())
            rows.update(np.argmax(flat, axis=0).tolist())
        for i in sorted(rows):
            self.message(i)
