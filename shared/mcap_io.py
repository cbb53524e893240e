"""Read fixstream MCAP recordings: finalised files and files cut short by a crash.

The recorder (``services/recorder``) writes one channel per key expression, a ``jsonschema`` schema
named ``fixstream.<Model>`` per model and ``json`` messages, in compressed chunks. This module reads such
files back for the player's MCAP replay, the tests and the report tool:

* :func:`iter_records` yields every message in file order as a :class:`Record`. It reads the data section
  sequentially and needs neither the summary nor the footer, so a file whose writer was killed
  (SIGKILL, power loss) yields everything up to its last complete chunk and then stops, without an
  exception.
* :func:`decode_record` turns a record back into the strict pydantic model.
* :func:`count_by_topic` counts messages per topic (channel topic = Zenoh key expression).
* :func:`recording_files` lists the (rotated) files of a recording directory in recording order.

Anything that is not a readable MCAP file raises :class:`McapReadError` naming the file and what is
wrong with it: a missing file, an empty file, a file that does not start with the MCAP magic, a file
cut inside its header, a chunk that fails to decompress or whose CRC does not match.

Truncation versus corruption: a record whose length runs past the end of the file is taken as the tail
a crashed writer left behind and ends the iteration quietly; a complete record whose content is
malformed is corruption and raises. (A corrupted length field that points past the end of the file is
indistinguishable from truncation and therefore also ends the iteration.)

The record layouts parsed here follow the MCAP specification (https://mcap.dev/spec); they are parsed with
bounds checks so that a malformed record is reported, never half-read.
"""

from __future__ import annotations

import os
import struct
import zlib
from collections import Counter
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from schemas import MODELS, Message

#: the 8 bytes every MCAP file starts (and a finalised file ends) with
MAGIC = b"\x89MCAP0\r\n"
#: schema encoding and message encoding the recorder uses (MCAP well-known values, read by Foxglove)
SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"
#: prefix of every fixstream schema name: ``fixstream.<Model>``
SCHEMA_PREFIX = "fixstream."
#: channel metadata key holding the Zenoh encoding string the message arrived with
ENCODING_METADATA_KEY = "zenoh_encoding"

_OP_HEADER = 0x01
_OP_FOOTER = 0x02
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06
_OP_DATA_END = 0x0F
_RECORD_PREFIX = 9  # opcode (1 byte) + length (8 bytes)


class McapReadError(ValueError):
    """A file that cannot be read as an MCAP recording, or a record that cannot be decoded.

    ``str(exc)`` names the file (or topic) and the problem; ``reason`` is a short code for counters:
    ``missing``, ``unreadable``, ``empty``, ``not_mcap``, ``truncated_header``, ``corrupt`` (file level),
    ``unknown_schema``, ``schema_version``, ``bad_encoding``, ``invalid_message`` (record level).
    """

    def __init__(self, where: str | os.PathLike[str], problem: str, reason: str = "unreadable") -> None:
        super().__init__(f"{os.fspath(where)}: {problem}")
        #: the file (or, from :func:`decode_record`, the topic) the problem is in
        self.where = os.fspath(where)
        self.problem = problem
        self.reason = reason


@dataclass(frozen=True)
class Record:
    """One message of a recording, with what is needed to decode it.

    Times are nanoseconds: ``log_time_ns`` is when the recorder received the message (wall clock, UNIX
    epoch), ``publish_time_ns`` is the message's ``header.stamp_ns`` (scenario clock).
    """

    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes = field(repr=False)
    sequence: int = 0
    channel_metadata: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class _Schema:
    name: str
    encoding: str


@dataclass(frozen=True)
class _Channel:
    topic: str
    message_encoding: str
    schema_id: int
    metadata: Mapping[str, str]


class _Malformed(Exception):
    """A record body shorter than its fields or otherwise not following the MCAP layout."""


class _Cursor:
    """Little-endian reader over one record body; every read is bounds-checked."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.pos = 0

    def take(self, n: int) -> bytes:
        if n < 0 or self.pos + n > len(self.data):
            raise _Malformed(f"field of {n} bytes runs past the end of the record ({len(self.data)} bytes)")
        out = self.data[self.pos : self.pos + n]
        self.pos += n
        return out

    def u16(self) -> int:
        return int(struct.unpack("<H", self.take(2))[0])

    def u32(self) -> int:
        return int(struct.unpack("<I", self.take(4))[0])

    def u64(self) -> int:
        return int(struct.unpack("<Q", self.take(8))[0])

    def string(self) -> str:
        raw = self.take(self.u32())
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise _Malformed(f"string is not UTF-8: {exc}") from None

    def rest(self) -> bytes:
        return self.take(len(self.data) - self.pos)

    @property
    def at_end(self) -> bool:
        return self.pos >= len(self.data)


def _parse_schema(body: bytes) -> tuple[int, _Schema]:
    c = _Cursor(body)
    schema_id = c.u16()
    name = c.string()
    encoding = c.string()
    c.take(c.u32())  # schema data (the JSON Schema); not needed to read messages
    return schema_id, _Schema(name=name, encoding=encoding)


def _parse_channel(body: bytes) -> tuple[int, _Channel]:
    c = _Cursor(body)
    channel_id = c.u16()
    schema_id = c.u16()
    topic = c.string()
    message_encoding = c.string()
    meta = _Cursor(c.take(c.u32()))
    metadata: dict[str, str] = {}
    while not meta.at_end:
        key = meta.string()
        metadata[key] = meta.string()
    return channel_id, _Channel(topic=topic, message_encoding=message_encoding, schema_id=schema_id, metadata=metadata)


def _decompress(compression: str, data: bytes, uncompressed_size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        return bytes(zstandard.ZstdDecompressor().decompress(data, max_output_size=uncompressed_size))
    if compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.decompress(data))
    raise _Malformed(f"unsupported chunk compression {compression!r}")


def _chunk_records(body: bytes) -> list[tuple[int, bytes]]:
    """The (opcode, body) records inside a chunk record, decompressed and CRC-checked."""
    c = _Cursor(body)
    c.u64()  # message start time
    c.u64()  # message end time
    uncompressed_size = c.u64()
    uncompressed_crc = c.u32()
    compression = c.string()
    compressed = c.take(c.u64())
    try:
        data = _decompress(compression, compressed, uncompressed_size)
    except _Malformed:
        raise
    except Exception as exc:  # zstd/lz4 raise their own error types
        raise _Malformed(f"{compression} decompression failed: {type(exc).__name__}: {exc}") from None
    if len(data) != uncompressed_size:
        raise _Malformed(f"decompressed to {len(data)} bytes, the chunk says {uncompressed_size}")
    if uncompressed_crc != 0 and zlib.crc32(data) != uncompressed_crc:
        raise _Malformed(f"CRC mismatch: computed {zlib.crc32(data):#010x}, the chunk says {uncompressed_crc:#010x}")
    inner = _Cursor(data)
    out: list[tuple[int, bytes]] = []
    while not inner.at_end:
        opcode = inner.take(1)[0]
        out.append((opcode, inner.take(inner.u64())))
    return out


def _read_exact(f: BinaryIO, n: int) -> bytes:
    """Up to ``n`` bytes; fewer only at the end of the file."""
    chunks: list[bytes] = []
    remaining = n
    while remaining > 0:
        part = f.read(remaining)
        if not part:
            break
        chunks.append(part)
        remaining -= len(part)
    return b"".join(chunks)


def _open(path: Path) -> BinaryIO:
    try:
        return path.open("rb")
    except FileNotFoundError:
        raise McapReadError(path, "no such file", "missing") from None
    except IsADirectoryError:
        raise McapReadError(path, "is a directory, not an MCAP file", "not_mcap") from None
    except OSError as exc:
        raise McapReadError(path, f"cannot open: {exc.strerror or exc}", "unreadable") from None


def _check_start(path: Path, f: BinaryIO, size: int) -> None:
    """Magic and header record, or McapReadError."""
    if size == 0:
        raise McapReadError(path, "empty file (0 bytes), not an MCAP recording", "empty")
    magic = _read_exact(f, len(MAGIC))
    if magic != MAGIC[: len(magic)]:
        raise McapReadError(
            path,
            f"not an MCAP file: starts with {magic.hex(' ')}, MCAP files start with {MAGIC.hex(' ')}",
            "not_mcap",
        )
    if len(magic) < len(MAGIC):
        raise McapReadError(
            path, f"truncated inside the header: {size} bytes, the 8-byte MCAP magic is incomplete", "truncated_header"
        )
    prefix = _read_exact(f, _RECORD_PREFIX)
    if len(prefix) < _RECORD_PREFIX:
        raise McapReadError(
            path, f"truncated inside the header: {size} bytes, no complete header record", "truncated_header"
        )
    opcode, length = prefix[0], int(struct.unpack("<Q", prefix[1:])[0])
    if opcode != _OP_HEADER:
        raise McapReadError(
            path, f"corrupt: the first record has opcode {opcode:#04x}, expected a header (0x01)", "corrupt"
        )
    body = _read_exact(f, length) if length <= size else b""
    if len(body) < length or length > size:
        raise McapReadError(
            path, f"truncated inside the header: {size} bytes, the header record needs {length}", "truncated_header"
        )
    try:
        c = _Cursor(body)
        c.string()  # profile
        c.string()  # library
    except _Malformed as exc:
        raise McapReadError(path, f"corrupt header record: {exc}", "corrupt") from None


def iter_records(path: str | os.PathLike[str]) -> Iterator[Record]:
    """Every message of an MCAP file in file order (the recorder's receive order).

    Reads finalised files and files whose writer died: iteration ends quietly at the first incomplete
    record, so a crashed recording yields every message of its complete chunks. Raises
    :class:`McapReadError` for a missing, empty or non-MCAP file, one truncated inside its header, or a
    complete record that is corrupt (bad chunk compression or CRC, message on an undeclared channel).
    """
    p = Path(path)
    f = _open(p)
    try:
        size = os.fstat(f.fileno()).st_size
        _check_start(p, f, size)  # eagerly, so a bad file raises here rather than at the first next()
    except BaseException:
        f.close()
        raise
    return _iter_data_section(p, f, size)


def _iter_data_section(p: Path, f: BinaryIO, size: int) -> Iterator[Record]:
    with f:
        schemas: dict[int, _Schema] = {}
        channels: dict[int, _Channel] = {}
        while True:
            offset = f.tell()
            prefix = _read_exact(f, _RECORD_PREFIX)
            if len(prefix) < _RECORD_PREFIX:
                return  # end of file without a footer: the writer stopped here
            opcode, length = prefix[0], int(struct.unpack("<Q", prefix[1:])[0])
            if length > size - offset - _RECORD_PREFIX:
                return  # the record runs past the end of the file: a truncated tail
            body = _read_exact(f, length)
            if len(body) < length:
                return
            if opcode in (_OP_FOOTER, _OP_DATA_END):
                return  # the data section is over; the summary holds no messages
            try:
                records = _chunk_records(body) if opcode == _OP_CHUNK else [(opcode, body)]
                batch = [r for r in (_apply(op, b, schemas, channels) for op, b in records) if r is not None]
            except _Malformed as exc:
                what = "chunk" if opcode == _OP_CHUNK else f"record (opcode {opcode:#04x})"
                raise McapReadError(p, f"corrupt {what} at byte offset {offset}: {exc}", "corrupt") from None
            yield from batch


def _apply(opcode: int, body: bytes, schemas: dict[int, _Schema], channels: dict[int, _Channel]) -> Record | None:
    """Register a schema or channel, or build the Record of a message; other records are skipped."""
    if opcode == _OP_SCHEMA:
        schema_id, schema = _parse_schema(body)
        schemas[schema_id] = schema
        return None
    if opcode == _OP_CHANNEL:
        channel_id, channel = _parse_channel(body)
        if channel.schema_id != 0 and channel.schema_id not in schemas:
            raise _Malformed(f"channel {channel_id} ({channel.topic}) refers to undeclared schema {channel.schema_id}")
        channels[channel_id] = channel
        return None
    if opcode != _OP_MESSAGE:
        return None
    c = _Cursor(body)
    channel_id = c.u16()
    sequence = c.u32()
    log_time = c.u64()
    publish_time = c.u64()
    data = c.rest()
    chan = channels.get(channel_id)
    if chan is None:
        raise _Malformed(f"message on undeclared channel {channel_id}")
    schema = schemas.get(chan.schema_id, _Schema(name="", encoding=""))
    return Record(
        topic=chan.topic,
        schema_name=schema.name,
        schema_encoding=schema.encoding,
        message_encoding=chan.message_encoding,
        log_time_ns=log_time,
        publish_time_ns=publish_time,
        data=data,
        sequence=sequence,
        channel_metadata=chan.metadata,
    )


def model_of(record: Record) -> type[Message]:
    """The pydantic model of a record, from its schema name ``fixstream.<Model>`` (and version if recorded)."""
    if not record.schema_name.startswith(SCHEMA_PREFIX):
        raise McapReadError(record.topic, f"schema {record.schema_name!r} is not a fixstream schema", "unknown_schema")
    name = record.schema_name.removeprefix(SCHEMA_PREFIX)
    model = MODELS.get(name)
    if model is None:
        raise McapReadError(
            record.topic, f"no model named {name!r} in this build (schema {record.schema_name!r})", "unknown_schema"
        )
    wire = record.channel_metadata.get(ENCODING_METADATA_KEY, "")
    if wire and not wire.endswith(model.schema_id()):
        raise McapReadError(
            record.topic, f"recorded as {wire!r}, this build speaks {model.schema_id()}", "schema_version"
        )
    return model


def decode_record(record: Record) -> Message:
    """JSON message data back to its strict pydantic model; McapReadError names the topic and the problem."""
    if record.message_encoding != MESSAGE_ENCODING:
        raise McapReadError(
            record.topic, f"message encoding {record.message_encoding!r}, expected 'json'", "bad_encoding"
        )
    model = model_of(record)
    from pydantic import ValidationError

    try:
        return model.model_validate_json(record.data, strict=True)
    except ValidationError as exc:
        first = exc.errors(include_url=False)[0]
        loc = ".".join(str(p) for p in first.get("loc", ())) or "<root>"
        raise McapReadError(
            record.topic,
            f"{model.__name__}.{loc}: {first.get('msg')} ({exc.error_count()} error(s))",
            "invalid_message",
        ) from None


def count_by_topic(path: str | os.PathLike[str]) -> dict[str, int]:
    """Messages per topic, counted over the readable part of the file (see :func:`iter_records`)."""
    return dict(Counter(r.topic for r in iter_records(path)))


def recording_files(directory: str | os.PathLike[str], prefix: str = "") -> list[Path]:
    """The ``*.mcap`` files of a directory (optionally only ``<prefix>_*``), in recording order.

    The recorder names files ``<prefix>_<UTC yyyymmddThhmmssZ>_<nnn>.mcap``, so name order is time order.
    """
    pattern = f"{prefix}_*.mcap" if prefix else "*.mcap"
    return sorted(p for p in Path(directory).glob(pattern) if p.is_file())


__all__ = [
    "ENCODING_METADATA_KEY",
    "MAGIC",
    "MESSAGE_ENCODING",
    "SCHEMA_ENCODING",
    "SCHEMA_PREFIX",
    "McapReadError",
    "Record",
    "count_by_topic",
    "decode_record",
    "iter_records",
    "model_of",
    "recording_files",
]
