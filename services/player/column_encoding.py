"""The bytes of a column stream's messages, many rows at a time, without building a message per row.

What is written is exactly ``codec.encode_stamped(stream.message(i), source, seq)``: msgpack of the model's
serialised dict (``header`` first, fields in model order) with ``header.source`` and ``header.seq`` replaced.
msgpack is compositional (a map is its header, then each key's bytes and each value's bytes in order) and a
Python float is always written as a float 64 (``0xcb`` + 8 big-endian bytes), so a row's bytes are

    constant bytes | header.stamp_ns | constant bytes | header.seq | constant bytes | float | ... | float | ...

where every piece but the two integers has the same width in every row. :func:`layout` finds the pieces from the
serialised first row (a template: keys, constants and the places of the column values), and :class:`RowEncoder`
fills a ``(rows, width)`` byte array per block of rows with numpy: constants broadcast, floats as ``>f8``, the
integers in the msgpack width class of their value (positive fixint, uint 8/16/32/64; rows of one block are grouped
by the classes of their stamp and seq). A stream whose columns are not all floats is encoded from the template dict
instead, one ``msgpack`` call per row (same bytes, slower).

``tests/test_player_fast_path.py`` compares both paths with the per-message encoding, byte for byte.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import msgpack
import numpy as np

from .simulators.columns import CHUNK_ROWS, ColumnStream

#: msgpack's unsigned integer formats: width class -> (first byte or None for a positive fixint, big-endian dtype)
_UINT_FORMATS: tuple[tuple[int | None, str | None], ...] = (
    (None, None),  # 0 <= v < 2**7: the byte itself
    (0xCC, ">u1"),
    (0xCD, ">u2"),
    (0xCE, ">u4"),
    (0xCF, ">u8"),
)
_UINT_WIDTH = (1, 2, 3, 5, 9)
_FLOAT64 = 0xCB


def uint_class(v: np.ndarray) -> np.ndarray:
    """msgpack width class of each non-negative integer (index into the formats: fixint, uint8 ... uint64)."""
    return (v >= 1 << 7).astype(np.int64) + (v >= 1 << 8) + (v >= 1 << 16) + (v >= 1 << 32)


@dataclass(frozen=True)
class Piece:
    """A run of constant bytes (``const``), or a slot: ``"stamp"``, ``"seq"`` or a float column (name, component)."""

    const: bytes = b""
    slot: str = ""
    column: str = ""
    component: int | None = None


def layout(template: dict[str, Any], columns: dict[str, np.ndarray]) -> list[Piece] | None:
    """The pieces of a row's bytes, or None if some column is not float (then its width may vary by row)."""
    if any(not np.issubdtype(c.dtype, np.floating) for c in columns.values()):
        return None
    packer = msgpack.Packer(use_bin_type=True, autoreset=True)
    pieces: list[Piece] = []

    def const(b: bytes) -> None:
        if pieces and pieces[-1].const and not pieces[-1].slot:
            pieces[-1] = Piece(const=pieces[-1].const + b)
        else:
            pieces.append(Piece(const=b))

    const(packer.pack_map_header(len(template)))
    for name, value in template.items():
        const(packer.pack(name))
        if name == "header":
            const(packer.pack_map_header(len(value)))
            for field, v in value.items():
                const(packer.pack(field))
                if field in ("stamp_ns", "seq"):
                    pieces.append(Piece(slot="stamp" if field == "stamp_ns" else "seq"))
                else:
                    const(packer.pack(v))
        elif name in columns:
            col = columns[name]
            if col.ndim == 1:
                pieces.append(Piece(slot="float", column=name))
            else:
                const(packer.pack_array_header(col.shape[1]))
                pieces.extend(Piece(slot="float", column=name, component=j) for j in range(col.shape[1]))
        elif isinstance(value, dict) and any(c.startswith(f"{name}.") for c in columns):
            const(packer.pack_map_header(len(value)))
            for child, v in value.items():
                const(packer.pack(child))
                full = f"{name}.{child}"
                if full in columns:
                    pieces.append(Piece(slot="float", column=full))
                else:
                    const(packer.pack(v))
        else:
            const(packer.pack(value))
    return pieces


class RowEncoder:
    """Rows of one column stream as bytes, in row order; ``seqs[i]`` is row ``i``'s ``header.seq``.

    :meth:`take` gives the next rows. :meth:`shift` adds to the seq of every row not yet taken (another simulator
    published on the same key)."""

    def __init__(self, stream: ColumnStream, source: str, seqs: np.ndarray) -> None:
        self.stream = stream
        self.seqs = seqs
        first = stream.message(0)
        self.template: dict[str, Any] = first.__pydantic_serializer__.to_python(first)
        self.template["header"]["source"] = source
        self.pieces = layout(self.template, stream.columns)
        self._offset = 0  #: added to ``seqs`` of the rows not yet encoded
        self._pos = 0  #: next row to take
        self._buf: list[bytes] = []
        self._buf_lo = 0  #: row of ``_buf[0]``

    @property
    def taken(self) -> int:
        """Rows taken so far."""
        return self._pos

    def shift(self, by: int) -> None:
        self._offset += by
        self._buf = self._buf[: self._pos - self._buf_lo]  # rows already taken stay; the rest is re-encoded

    def take(self, m: int) -> list[bytes]:
        """The bytes of the next ``m`` rows."""
        out: list[bytes] = []
        while len(out) < m:
            have = self._buf_lo + len(self._buf) - self._pos
            if have <= 0:
                lo = self._pos
                hi = min(lo + max(CHUNK_ROWS, m - len(out)), len(self.stream))
                if lo >= hi:
                    raise IndexError(f"{self.stream.key}: no row {lo}")
                self._buf, self._buf_lo = self.encode(lo, hi), lo
                have = hi - lo
            k = min(have, m - len(out))
            start = self._pos - self._buf_lo
            out.extend(self._buf[start : start + k])
            self._pos += k
        return out

    def encode(self, lo: int, hi: int) -> list[bytes]:
        """Rows ``lo`` to ``hi - 1`` as bytes (their seq: ``seqs`` plus the current shift)."""
        stamps = self.stream.stamps_ns[lo:hi]
        seqs = self.seqs[lo:hi] + self._offset
        if self.pieces is None:
            return self._encode_dicts(lo, hi, stamps, seqs)
        classes = uint_class(stamps) * len(_UINT_WIDTH) + uint_class(seqs)
        groups = np.unique(classes)
        if groups.size == 1:
            return self._encode_block(lo, hi, slice(None), stamps, seqs, int(groups[0]))
        out: list[bytes] = [b""] * (hi - lo)
        for g in groups.tolist():
            rows = np.flatnonzero(classes == g)
            for i, payload in zip(rows.tolist(), self._encode_block(lo, hi, rows, stamps, seqs, g), strict=True):
                out[i] = payload
        return out

    def _encode_block(
        self, lo: int, hi: int, rows: slice | np.ndarray, stamps: np.ndarray, seqs: np.ndarray, group: int
    ) -> list[bytes]:
        """Rows ``lo + rows`` whose stamp and seq are in the width classes ``group`` (stamp class * 5 + seq class)."""
        assert self.pieces is not None
        stamp_class, seq_class = divmod(group, len(_UINT_WIDTH))
        widths = []
        for p in self.pieces:
            if p.slot == "stamp":
                widths.append(_UINT_WIDTH[stamp_class])
            elif p.slot == "seq":
                widths.append(_UINT_WIDTH[seq_class])
            elif p.slot == "float":
                widths.append(9)
            else:
                widths.append(len(p.const))
        width = sum(widths)
        m = len(stamps[rows])
        buf = np.empty((m, width), dtype=np.uint8)
        off = 0
        for p, w in zip(self.pieces, widths, strict=True):
            if p.slot == "stamp":
                _put_uint(buf, off, stamps[rows], stamp_class)
            elif p.slot == "seq":
                _put_uint(buf, off, seqs[rows], seq_class)
            elif p.slot == "float":
                col = self.stream.columns[p.column][lo:hi][rows]
                values = col if p.component is None else col[:, p.component]
                buf[:, off] = _FLOAT64
                buf[:, off + 1 : off + 9] = values.astype(">f8").view(np.uint8).reshape(m, 8)
            else:
                buf[:, off : off + w] = np.frombuffer(p.const, dtype=np.uint8)
            off += w
        data = buf.tobytes()
        return [data[i : i + width] for i in range(0, m * width, width)]

    def _encode_dicts(self, lo: int, hi: int, stamps: np.ndarray, seqs: np.ndarray) -> list[bytes]:
        template = self.template
        header = template["header"]
        names, values = self.stream.field_values(lo, hi)
        pack = msgpack.Packer(use_bin_type=True, autoreset=True).pack
        out = []
        for stamp, seq, row in zip(stamps.tolist(), seqs.tolist(), zip(*values, strict=True), strict=True):
            header["stamp_ns"] = stamp
            header["seq"] = seq
            template.update(zip(names, row, strict=True))
            out.append(pack(template))
        return out


def _put_uint(buf: np.ndarray, off: int, v: np.ndarray, cls: int) -> None:
    """msgpack unsigned integers of width class ``cls`` into columns ``off...`` of ``buf``."""
    first, dtype = _UINT_FORMATS[cls]
    if first is None:
        buf[:, off] = v
        return
    assert dtype is not None
    buf[:, off] = first
    w = _UINT_WIDTH[cls]
    buf[:, off + 1 : off + w] = v.astype(dtype).view(np.uint8).reshape(len(v), w - 1)
