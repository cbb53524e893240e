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
* :func:`scan` reads a whole file once and summarises it (topics with counts and data-clock span, schemas,
  compression, metadata, attachments, finalised or truncated): what ``fixstream info`` prints.
* :func:`recover` rewrites a file cut short by a crash as a finalised one (summary, indexes, footer), so that
  readers that need the footer (the ``mcap`` package's ``make_reader``, Foxglove) open it.
* :class:`Rejected` is a payload the recorder could not decode or validate, kept byte for byte on the topic
  ``fixstream/rejected/<original key>`` (:func:`encode_rejected`, :func:`decode_rejected`).

**Time fields** (docs/recorder.md): ``log_time`` = ``publish_time`` = the message's ``header.stamp_ns``, the data
clock (the Rust MCAP writer of ``foxglove-sdk`` writes the same value in both). A rejected payload carries the
stamp of its header when it has a readable one, else the data clock of the last valid message. The wall time a
sample arrived is kept only for rejected payloads (``rx_time_ns`` in their envelope).

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

import base64
import json
import os
import struct
import zlib
from collections import Counter
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from schemas import MODELS, Message

from .codec import MAX_PAYLOAD_BYTES

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
_OP_ATTACHMENT = 0x09
_OP_METADATA = 0x0C
_OP_DATA_END = 0x0F
_RECORD_PREFIX = 9  # opcode (1 byte) + length (8 bytes)


class McapReadError(ValueError):
    """A file that cannot be read as an MCAP recording, or a record that cannot be decoded.

    ``str(exc)`` names the file (or topic) and the problem; ``reason`` is a short code for counters:
    ``missing``, ``unreadable``, ``empty``, ``not_mcap``, ``truncated_header``, ``corrupt`` (file level),
    ``unknown_schema``, ``schema_version``, ``bad_encoding``, ``invalid_message``, ``too_large`` (record level).
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

    Times are nanoseconds on the data clock: in a fixstream recording both are the message's ``header.stamp_ns``
    (see the module doc); files of other writers may put a receive time in ``log_time_ns``.
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
    #: the schema's data (a JSON Schema for fixstream channels), shared by every record of the schema
    schema_data: bytes = field(default=b"", repr=False, compare=False)


@dataclass(frozen=True)
class _Schema:
    name: str
    encoding: str
    data: bytes = b""


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
    data = c.take(c.u32())  # the JSON Schema
    return schema_id, _Schema(name=name, encoding=encoding, data=data)


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


def _chunk_records(body: bytes) -> tuple[str, list[tuple[int, bytes]]]:
    """The chunk's compression and the (opcode, body) records inside it, decompressed and CRC-checked."""
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
    return compression, out


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


def _check_start(path: Path, f: BinaryIO, size: int) -> tuple[str, str]:
    """Magic and header record (returns its profile and library), or McapReadError."""
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
        return c.string(), c.string()  # profile, library
    except _Malformed as exc:
        raise McapReadError(path, f"corrupt header record: {exc}", "corrupt") from None


def iter_records(path: str | os.PathLike[str], progress: ReadProgress | None = None) -> Iterator[Record]:
    """Every message of an MCAP file in file order (the recorder's receive order).

    Reads finalised files and files whose writer died: iteration ends quietly at the first incomplete
    record, so a crashed recording yields every message of its complete chunks (``progress``, when given, says
    afterwards whether the data section ended properly and where the last complete record ended). Raises
    :class:`McapReadError` for a missing, empty or non-MCAP file, one truncated inside its header, or a
    complete record that is corrupt (bad chunk compression or CRC, message on an undeclared channel).
    """
    return (item for item in iter_items(path, progress) if type(item) is Record)


@dataclass(frozen=True)
class MetadataRecord:
    """An MCAP metadata record: a name and string key/value pairs."""

    name: str
    metadata: Mapping[str, str]


@dataclass(frozen=True)
class AttachmentRecord:
    """An MCAP attachment: a named file (e.g. the scenario YAML) kept in the recording."""

    name: str
    media_type: str
    log_time_ns: int
    create_time_ns: int
    data: bytes = field(repr=False)


@dataclass(frozen=True)
class ChunkSeen:
    """A complete chunk record (yielded before its messages): where it is and how it is compressed."""

    offset: int
    length: int
    compression: str


@dataclass
class ReadProgress:
    """How far a pass over the data section got (``end`` short of the file's size and no ``footer``: the file was cut
    short, or is still being written)."""

    header: tuple[str, str] = ("", "")  # (profile, library)
    end: int = 0  # offset after the last complete record
    footer: bool = False  # the data section ended with DataEnd or a Footer


Item = Record | MetadataRecord | AttachmentRecord | ChunkSeen


def iter_items(path: str | os.PathLike[str], progress: ReadProgress | None = None) -> Iterator[Item]:
    """Messages, metadata, attachments and chunk boundaries of the data section, in file order (see
    :func:`iter_records` for what is read and what raises). ``progress`` is filled as the pass goes."""
    p = Path(path)
    f = _open(p)
    progress = progress if progress is not None else ReadProgress()
    try:
        size = os.fstat(f.fileno()).st_size
        progress.header = _check_start(p, f, size)  # eagerly: a bad file raises here, not at the first next()
        progress.end = f.tell()
    except BaseException:
        f.close()
        raise
    return _iter_data_section(p, f, size, progress)


def _iter_data_section(p: Path, f: BinaryIO, size: int, progress: ReadProgress) -> Iterator[Item]:
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
                progress.footer = True
                return  # the data section is over; the summary holds no messages
            try:
                batch: list[Item] = []
                if opcode == _OP_CHUNK:
                    compression, records = _chunk_records(body)
                    batch.append(ChunkSeen(offset, _RECORD_PREFIX + length, compression))
                elif opcode == _OP_METADATA:
                    batch.append(_parse_metadata(body))
                    records = []
                elif opcode == _OP_ATTACHMENT:
                    batch.append(_parse_attachment(body))
                    records = []
                else:
                    records = [(opcode, body)]
                batch.extend(r for r in (_apply(op, b, schemas, channels) for op, b in records) if r is not None)
            except _Malformed as exc:
                what = "chunk" if opcode == _OP_CHUNK else f"record (opcode {opcode:#04x})"
                raise McapReadError(p, f"corrupt {what} at byte offset {offset}: {exc}", "corrupt") from None
            progress.end = f.tell()
            yield from batch


def _parse_metadata(body: bytes) -> MetadataRecord:
    c = _Cursor(body)
    name = c.string()
    meta = _Cursor(c.take(c.u32()))
    pairs: dict[str, str] = {}
    while not meta.at_end:
        key = meta.string()
        pairs[key] = meta.string()
    return MetadataRecord(name, pairs)


def _parse_attachment(body: bytes) -> AttachmentRecord:
    c = _Cursor(body)
    log_time = c.u64()
    create_time = c.u64()
    name = c.string()
    media_type = c.string()
    data = c.take(c.u64())
    crc = c.u32()
    if crc != 0 and zlib.crc32(body[: c.pos - 4]) != crc:
        raise _Malformed(f"attachment {name!r}: CRC mismatch")
    return AttachmentRecord(name, media_type, log_time, create_time, data)


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
        schema_data=schema.data,
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


#: the largest JSON message decoded, bytes: four times the largest payload a service or the recorder takes
#: (``codec.MAX_PAYLOAD_BYTES``, msgpack; its JSON is at most about 2.5 times as long). A hostile file's one 50 MB
#: message once cost a replay and a report 1.1 GB each, for a message no service would take
MAX_JSON_MESSAGE_BYTES = 4 * MAX_PAYLOAD_BYTES


def decode_record(record: Record) -> Message:
    """JSON message data back to its strict pydantic model; McapReadError names the topic and the problem (a message
    over ``MAX_JSON_MESSAGE_BYTES``: ``too_large``, before any decoding)."""
    if len(record.data) > MAX_JSON_MESSAGE_BYTES:
        raise McapReadError(
            record.topic, f"{len(record.data)} bytes of JSON > {MAX_JSON_MESSAGE_BYTES}: not decoded", "too_large"
        )
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


# ----- the rejected-payload channel ------------------------------------------------------------------------

#: topic prefix of rejected payloads: ``fixstream/rejected/<original key>``
REJECTED_PREFIX = "fixstream/rejected/"
#: schema name of the rejected-payload envelope (not a ``fixstream.<Model>``: no model decodes it)
REJECTED_SCHEMA = "fixstream_raw.RejectedPayload"
#: its JSON Schema (Foxglove shows the envelope; ``payload`` is the original bytes, base64)
REJECTED_JSON_SCHEMA: dict[str, Any] = {
    "title": REJECTED_SCHEMA,
    "description": "A payload that failed decoding or validation, kept byte for byte so a replay puts it back.",
    "type": "object",
    "properties": {
        "key": {"type": "string", "description": "the Zenoh key it arrived on"},
        "encoding": {"type": "string", "description": "the Zenoh encoding it arrived with"},
        "reason": {"type": "string", "description": "why it was rejected (a reason code, as in the diagnostics)"},
        "detail": {"type": "string", "description": "what exactly was wrong"},
        "size": {"type": "integer", "description": "payload size, bytes"},
        "rx_time_ns": {"type": "integer", "description": "wall time it arrived, ns since the UNIX epoch"},
        "payload": {"type": "string", "contentEncoding": "base64", "description": "the payload bytes"},
    },
    "required": ["key", "encoding", "reason", "payload"],
}


@dataclass(frozen=True)
class Rejected:
    """A payload that failed decoding or validation, as it arrived."""

    key: str
    encoding: str
    reason: str
    detail: str
    payload: bytes = field(repr=False)
    rx_time_ns: int = 0

    @property
    def topic(self) -> str:
        return REJECTED_PREFIX + self.key


def encode_rejected(r: Rejected) -> bytes:
    """The JSON envelope of a rejected payload (message data on its ``fixstream/rejected/<key>`` channel)."""
    return json.dumps(
        {
            "key": r.key,
            "encoding": r.encoding,
            "reason": r.reason,
            "detail": r.detail,
            "size": len(r.payload),
            "rx_time_ns": r.rx_time_ns,
            "payload": base64.b64encode(r.payload).decode("ascii"),
        },
        separators=(",", ":"),
    ).encode()


def is_rejected(record: Record) -> bool:
    return record.schema_name == REJECTED_SCHEMA


def decode_rejected(record: Record) -> Rejected:
    """The rejected payload a record of the rejected channel holds; McapReadError if it is not one."""
    if not is_rejected(record):
        raise McapReadError(record.topic, f"schema {record.schema_name!r} is not {REJECTED_SCHEMA}", "unknown_schema")
    try:
        doc = json.loads(record.data)
        return Rejected(
            key=str(doc["key"]),
            encoding=str(doc["encoding"]),
            reason=str(doc["reason"]),
            detail=str(doc.get("detail", "")),
            payload=base64.b64decode(doc["payload"], validate=True),
            rx_time_ns=int(doc.get("rx_time_ns", 0)),
        )
    except (ValueError, KeyError, TypeError) as exc:
        raise McapReadError(record.topic, f"bad rejected-payload envelope: {exc}", "invalid_message") from None


# ----- a whole file at once: fixstream info, fixstream info --recover --------------------------------------


@dataclass
class TopicStats:
    """One topic of a recording: its schema (the first channel's), how many messages, and their span on the data
    clock; ``schemas``: messages per schema name when the topic has channels of several (one key written with two
    models), else empty."""

    schema_name: str
    message_encoding: str
    count: int = 0
    first_ns: int = 0
    last_ns: int = 0
    schemas: Counter[str] = field(default_factory=Counter)

    @property
    def rate_hz(self) -> float:
        """Messages per second of data clock (0 for fewer than two messages or no span)."""
        span = (self.last_ns - self.first_ns) * 1e-9
        return (self.count - 1) / span if self.count > 1 and span > 0 else 0.0


@dataclass
class Scan:
    """What one pass over a recording found (:func:`scan`)."""

    path: Path
    size: int
    profile: str
    library: str
    #: the data section ended properly and the file ends with the MCAP magic (summary and footer written)
    finalised: bool
    #: bytes after the last complete record (what a crash left half-written); 0 for a finalised file
    tail_bytes: int
    chunks: int
    compression: Counter[str]
    topics: dict[str, TopicStats]
    metadata: list[MetadataRecord]
    attachments: list[AttachmentRecord]

    @property
    def messages(self) -> int:
        return sum(t.count for t in self.topics.values())

    @property
    def start_ns(self) -> int:
        return min((t.first_ns for t in self.topics.values() if t.count), default=0)

    @property
    def end_ns(self) -> int:
        return max((t.last_ns for t in self.topics.values() if t.count), default=0)


def scan(path: str | os.PathLike[str]) -> Scan:
    """Read a recording once (finalised or cut short) and summarise it; McapReadError as :func:`iter_records`."""
    p = Path(path)
    progress = ReadProgress()
    topics: dict[str, TopicStats] = {}
    metadata: list[MetadataRecord] = []
    attachments: list[AttachmentRecord] = []
    compression: Counter[str] = Counter()
    chunks = 0
    for item in iter_items(p, progress):
        if type(item) is Record:
            t = topics.get(item.topic)
            if t is None:
                t = topics[item.topic] = TopicStats(item.schema_name, item.message_encoding, 0, item.log_time_ns, 0)
            t.count += 1
            if t.schemas or item.schema_name != t.schema_name:  # a second model on the key: count them apart
                if not t.schemas:
                    t.schemas[t.schema_name] = t.count - 1
                t.schemas[item.schema_name] += 1
            t.first_ns = min(t.first_ns, item.log_time_ns)
            t.last_ns = max(t.last_ns, item.log_time_ns)
        elif type(item) is ChunkSeen:
            chunks += 1
            compression[item.compression or "none"] += 1
        elif type(item) is MetadataRecord:
            metadata.append(item)
        elif type(item) is AttachmentRecord:
            attachments.append(item)
    size = p.stat().st_size
    finalised = progress.footer and _ends_with_magic(p, size)
    return Scan(
        path=p,
        size=size,
        profile=progress.header[0],
        library=progress.header[1],
        finalised=finalised,
        tail_bytes=0 if progress.footer else size - progress.end,
        chunks=chunks,
        compression=compression,
        topics=topics,
        metadata=metadata,
        attachments=attachments,
    )


def _ends_with_magic(p: Path, size: int) -> bool:
    if size < 2 * len(MAGIC):
        return False
    with p.open("rb") as f:
        f.seek(size - len(MAGIC))
        return f.read(len(MAGIC)) == MAGIC


def recover(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> Scan:
    """Rewrite ``src`` (typically cut short by a crash) as a finalised MCAP file ``dst``: every message of its
    complete chunks with its times and sequence, its schemas, channels, metadata and attachments, then the summary
    and footer. ``dst`` must not exist. Returns the scan of the new file."""
    from mcap.writer import CompressionType, Writer

    src_p, dst_p = Path(src), Path(dst)
    first = scan(src_p)  # raises McapReadError for a file that is not a readable recording
    kinds = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4}
    compression = kinds.get(first.compression.most_common(1)[0][0] if first.compression else "", CompressionType.ZSTD)
    fd = os.open(dst_p, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o644)
    with os.fdopen(fd, "wb") as out:
        w = Writer(out, compression=compression)
        w.start(profile=first.profile, library=first.library or "fixstream-recover")
        # a schema is its name, encoding and data, a channel its topic, schema, encoding and metadata: two channels
        # of one topic that differ only in their metadata (e.g. the schema version a publisher declared) stay two
        # (merged, a replay of the recovered file published what the original's would skip as schema_version)
        schema_ids: dict[tuple[str, str, bytes], int] = {}
        channel_ids: dict[tuple[str, tuple[str, str, bytes], str, tuple[tuple[str, str], ...]], int] = {}
        for item in iter_items(src_p):
            if type(item) is Record:
                skey = (item.schema_name, item.schema_encoding, item.schema_data)
                sid = schema_ids.get(skey)
                if sid is None:
                    sid = (
                        0
                        if not item.schema_name
                        else w.register_schema(item.schema_name, item.schema_encoding, item.schema_data)
                    )
                    schema_ids[skey] = sid
                ckey = (item.topic, skey, item.message_encoding, tuple(sorted(item.channel_metadata.items())))
                cid = channel_ids.get(ckey)
                if cid is None:
                    cid = channel_ids[ckey] = w.register_channel(
                        item.topic, item.message_encoding, sid, dict(item.channel_metadata)
                    )
                w.add_message(cid, item.log_time_ns, item.data, item.publish_time_ns, item.sequence)
            elif type(item) is MetadataRecord:
                w.add_metadata(item.name, dict(item.metadata))
            elif type(item) is AttachmentRecord:
                w.add_attachment(item.create_time_ns, item.log_time_ns, item.name, item.media_type, item.data)
        w.finish()
        out.flush()
        os.fsync(out.fileno())
    return scan(dst_p)


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
    "REJECTED_JSON_SCHEMA",
    "REJECTED_PREFIX",
    "REJECTED_SCHEMA",
    "SCHEMA_ENCODING",
    "SCHEMA_PREFIX",
    "AttachmentRecord",
    "ChunkSeen",
    "McapReadError",
    "MetadataRecord",
    "Record",
    "Rejected",
    "Scan",
    "TopicStats",
    "count_by_topic",
    "decode_record",
    "decode_rejected",
    "encode_rejected",
    "is_rejected",
    "iter_items",
    "iter_records",
    "model_of",
    "recording_files",
    "recover",
    "scan",
]
