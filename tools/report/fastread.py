"""A fast path for reading finalised MCAP files: the data section parsed with ``struct.unpack_from`` on whole
decompressed chunks, messages decoded per channel with the model looked up once.

:mod:`shared.mcap_io` stays the authority: it reads truncated files, and it produces the error messages. This
module only handles files that end with the MCAP magic; on anything unexpected (an unknown compression, a record
that runs past its chunk, a CRC mismatch, a message on an undeclared channel, a message that does not validate)
it raises :class:`Fallback` and the caller reads the file with :mod:`shared.mcap_io` instead, which then either
reads it or raises its precise :class:`~shared.mcap_io.McapReadError`. Record layouts: https://mcap.dev/spec.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from schemas import Message
from shared.mcap_io import MAGIC, SCHEMA_PREFIX, McapReadError, Record, model_of

_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_FOOTER, _OP_DATA_END = 0x03, 0x04, 0x05, 0x06, 0x02, 0x0F


class Fallback(Exception):
    """The fast path cannot read this file; read it with :mod:`shared.mcap_io`."""


def _string(buf: bytes, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    end = pos + 4 + n
    if end > len(buf):
        raise Fallback("string past the end of its record")
    return buf[pos + 4 : end].decode("utf-8"), end


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        return bytes(zstandard.ZstdDecompressor().decompress(data, max_output_size=size))
    if compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.decompress(data))
    raise Fallback(f"compression {compression!r}")


def read_messages(path: Path, on_message: Callable[[str, Message], None], on_foreign: Callable[[str], None]) -> int:
    """Decode every message of a finalised file in file order: ``on_message(topic, msg)`` for fixstream channels,
    ``on_foreign(schema name)`` for the others. Returns the number of records; raises :class:`Fallback`."""
    data = path.read_bytes()
    if len(data) < 2 * len(MAGIC) or data[: len(MAGIC)] != MAGIC or data[-len(MAGIC) :] != MAGIC:
        raise Fallback("not a finalised MCAP file")
    schemas: dict[int, tuple[str, str]] = {}
    channels: dict[int, dict[str, Any]] = {}
    count = 0
    pos = len(MAGIC)
    end = len(data)
    unpack = struct.unpack_from

    def channel_model(cid: int, topic_meta: dict[str, Any]) -> Any:
        model = topic_meta.get("model", False)
        if model is False:
            name, _enc = schemas.get(topic_meta["schema_id"], ("", ""))
            if not name.startswith(SCHEMA_PREFIX):
                model = None
            else:
                rec = Record(
                    topic=topic_meta["topic"],
                    schema_name=name,
                    schema_encoding=_enc,
                    message_encoding=topic_meta["encoding"],
                    log_time_ns=0,
                    publish_time_ns=0,
                    data=b"",
                    channel_metadata=topic_meta["metadata"],
                )
                if topic_meta["encoding"] != "json":
                    raise Fallback("non-json fixstream channel")
                try:
                    model = model_of(rec)
                except McapReadError:
                    raise Fallback("unknown model") from None
            topic_meta["model"] = model
            topic_meta["schema_name"] = name
        return model

    def records(buf: bytes, start: int, stop: int) -> int:
        nonlocal count
        p = start
        while p < stop:
            if p + 9 > stop:
                raise Fallback("record header past the end")
            op = buf[p]
            (length,) = unpack("<Q", buf, p + 1)
            body = p + 9
            nxt = body + length
            if nxt > stop:
                raise Fallback("record past the end")
            if op == _OP_MESSAGE:
                cid, _seq, _lt, _pt = unpack("<HIQQ", buf, body)
                meta = channels.get(cid)
                if meta is None:
                    raise Fallback("message on an undeclared channel")
                model = channel_model(cid, meta)
                count += 1
                if model is None:
                    on_foreign(meta.get("schema_name") or "<no schema>")
                else:
                    try:
                        msg = model.model_validate_json(buf[body + 22 : nxt], strict=True)
                    except ValueError:
                        raise Fallback("invalid message") from None
                    on_message(meta["topic"], msg)
            elif op == _OP_SCHEMA:
                (sid,) = unpack("<H", buf, body)
                name, q = _string(buf, body + 2)
                enc, _ = _string(buf, q)
                schemas[sid] = (name, enc)
            elif op == _OP_CHANNEL:
                cid, sid = unpack("<HH", buf, body)
                topic, q = _string(buf, body + 4)
                enc, q = _string(buf, q)
                (mlen,) = unpack("<I", buf, q)
                meta_end = q + 4 + mlen
                md: dict[str, str] = {}
                q += 4
                while q < meta_end:
                    k, q = _string(buf, q)
                    v, q = _string(buf, q)
                    md[k] = v
                if sid != 0 and sid not in schemas:
                    raise Fallback("channel with an undeclared schema")
                channels[cid] = {"topic": topic, "encoding": enc, "schema_id": sid, "metadata": md}
            elif op in (_OP_FOOTER, _OP_DATA_END):
                return -1
            elif op == _OP_CHUNK:
                usize, crc = unpack("<QI", buf, body + 16)
                compression, q = _string(buf, body + 28)
                (clen,) = unpack("<Q", buf, q)
                try:
                    raw = _decompress(compression, buf[q + 8 : q + 8 + clen], usize)
                except Fallback:
                    raise
                except Exception as exc:  # zstd/lz4 raise their own types on corrupt data: mcap_io names it
                    raise Fallback(f"{compression}: {exc}") from None
                if len(raw) != usize or (crc != 0 and zlib.crc32(raw) != crc):
                    raise Fallback("chunk size or CRC")
                if records(raw, 0, len(raw)) < 0:
                    raise Fallback("footer inside a chunk")
            p = nxt
        return 0

    try:
        records(data, pos, end - len(MAGIC))
    except (struct.error, UnicodeDecodeError, IndexError) as exc:
        raise Fallback(str(exc)) from None
    return count


__all__ = ["Fallback", "read_messages"]
