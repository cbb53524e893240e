"""The recorder's MCAP output: one file at a time, chunked, compressed, rotated, crash-safe.

Layout of every file (what Foxglove and :mod:`shared.mcap_io` read):

* one schema per model: name ``fixstream.<Model>``, encoding ``jsonschema``, data = the model's JSON Schema
  (:func:`schemas.export.json_schema`);
* one channel per (key expression, model) — in practice one per key expression: topic = the key
  expression, message encoding ``json``, metadata ``zenoh_encoding`` = the wire encoding string;
* messages: data = the model's JSON, ``log_time`` = the recorder's receive wall time (ns, UNIX epoch),
  ``publish_time`` = ``header.stamp_ns``, ``sequence`` = ``header.seq`` (mod 2**32);
* compressed chunks (zstd, lz4 or none) with message indexes, and on :meth:`RotatingMcapWriter.finish`
  the summary section and footer.

Crash safety. The file is written through :class:`_DirectFile`, which hands every write straight to the
operating system (``os.write``; no user-space buffer), and the MCAP writer only writes whole records:
schemas, channels and messages go into the open chunk in memory, and a chunk is written in one piece when
it is closed. So after a SIGKILL the file holds every chunk that was closed, and at most the tail of one
record that was being written when the process died, which :func:`shared.mcap_io.iter_records` ignores.
A chunk is closed when it reaches ``chunk_size_bytes`` (the mcap writer does this itself) or, through the
public ``mcap.writer.Writer.flush()`` (which "finishes the chunk in progress"), when its oldest message
has waited ``chunk_flush_s`` seconds. A SIGKILL therefore loses at most the last ``chunk_flush_s``
seconds of messages (plus the time until the next :meth:`RotatingMcapWriter.poll`). Writes reach the
page cache, which survives a process crash; ``fsync`` is done only when a file is finalised.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, Literal, cast

from mcap.writer import CompressionType, Writer

from schemas import Message
from schemas.export import json_schema
from shared import codec
from shared.mcap_io import ENCODING_METADATA_KEY, MESSAGE_ENCODING, SCHEMA_ENCODING, SCHEMA_PREFIX

Compression = Literal["zstd", "lz4", "none"]
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
LIBRARY = "fixstream-recorder"


class _DirectFile:
    """A write-only binary file with no user-space buffer: each ``write`` is handed to the OS at once.

    The mcap writer accepts any object with ``write``, ``tell`` and ``flush``; unlike a ``BufferedWriter``
    this one never holds bytes a SIGKILL could lose. The mcap writer writes whole records (a closed chunk
    and its message indexes, the header, the summary), so the OS sees few, large writes.
    """

    def __init__(self, fd: int) -> None:
        self._fd = fd
        self._pos = 0
        self.closed = False

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data).cast("B")
        total = len(view)
        while view:
            n = os.write(self._fd, view)
            if n <= 0:
                raise OSError(f"os.write wrote {n} bytes")
            view = view[n:]
        self._pos += total
        return total

    def tell(self) -> int:
        """Bytes written so far (= the file size)."""
        return self._pos

    def flush(self) -> None:
        """Nothing is buffered here."""

    def close(self, sync: bool = True) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            if sync:
                os.fsync(self._fd)
        finally:
            os.close(self._fd)


@dataclass
class _OpenFile:
    """The file being written and what has been declared in it."""

    path: Path
    stream: _DirectFile
    writer: Writer
    opened_at: float  # monotonic, s
    schema_ids: dict[str, int] = field(default_factory=dict)
    channel_ids: dict[tuple[str, str], int] = field(default_factory=dict)
    messages: int = 0
    chunk_opened_at: float | None = None  # monotonic time the oldest message of the open chunk was added


class RotatingMcapWriter:
    """Writes messages to ``<out_dir>/<prefix>_<UTC yyyymmddThhmmssZ>_<nnn>.mcap``, rotating by size or age.

    A file is opened on the first message after construction or rotation (no empty files), closed with
    its summary and footer by :meth:`finish` or a rotation. Rotation by size happens once the bytes
    written reach ``rotate_size_bytes`` (a file can exceed it by one chunk, the summary and the footer);
    rotation by duration once the file is ``rotate_duration_s`` old (checked on every write and poll).
    File names are generated here, never taken from the input, and must resolve inside ``out_dir``;
    an existing file is never overwritten (``O_EXCL``), the counter moves on instead.
    """

    def __init__(
        self,
        out_dir: Path,
        *,
        prefix: str = "fixstream",
        compression: Compression = "zstd",
        chunk_size_bytes: int = 1 << 20,
        chunk_flush_s: float = 1.0,
        rotate_size_bytes: int = 0,
        rotate_duration_s: float = 0.0,
        metadata: dict[str, str] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if compression not in _COMPRESSION:
            raise ValueError(f"compression must be one of {sorted(_COMPRESSION)}, got {compression!r}")
        if not prefix or Path(prefix).name != prefix or ".." in prefix:
            raise ValueError(f"file prefix {prefix!r} must be a plain file name part")
        out_dir.mkdir(parents=True, exist_ok=True)
        self.out_dir = out_dir.resolve(strict=True)
        if not self.out_dir.is_dir():
            raise NotADirectoryError(f"{self.out_dir} is not a directory")
        self.prefix = prefix
        self.compression = compression
        self.chunk_size_bytes = chunk_size_bytes
        self.chunk_flush_s = chunk_flush_s
        self.rotate_size_bytes = rotate_size_bytes
        self.rotate_duration_s = rotate_duration_s
        self.metadata = dict(metadata or {})
        self._clock = clock
        self._file: _OpenFile | None = None
        self._next_index = 0
        self._schema_cache: dict[str, bytes] = {}
        #: finalised files, oldest first
        self.files_written: list[Path] = []
        #: fixstream messages written over all files
        self.messages_written = 0
        #: other messages (:meth:`write_raw`, e.g. the Foxglove channels) written over all files
        self.raw_written = 0
        #: chunks written over all files
        self.chunks_written = 0

    # ----- public API ---------------------------------------------------------------------------
    @property
    def current_path(self) -> Path | None:
        """The file being written, if any."""
        return self._file.path if self._file is not None else None

    @property
    def current_size_bytes(self) -> int:
        """Bytes of the current file on disk (closed chunks only)."""
        return self._file.stream.tell() if self._file is not None else 0

    def _current(self, now: float) -> _OpenFile:
        """The file to write to at ``now``: the open one, or a new one once rotation by duration is due."""
        f = self._file
        if f is not None and self._duration_due(f, now):
            self.finish()
            f = None
        if f is None:
            f = self._file = self._open(now)
        return f

    def write(self, topic: str, msg: Message, log_time_ns: int) -> None:
        """Add one message on channel ``topic`` (the key expression); ``log_time_ns`` is the receive time."""
        now = self._clock()
        f = self._current(now)
        start = f.stream.tell()
        channel_id = self._channel(f, topic, type(msg))  # may close a full chunk (schema/channel records)
        data = msg.model_dump_json().encode()
        self._add(f, start, now, channel_id, log_time_ns, data, msg.header.stamp_ns, msg.header.seq)

    def write_raw(
        self,
        topic: str,
        schema: tuple[str, str, bytes],
        message_encoding: str,
        data: bytes,
        log_time_ns: int,
        publish_time_ns: int,
        sequence: int = 0,
    ) -> None:
        """Add one already-encoded message on channel ``topic`` with ``schema`` = (name, encoding, data), e.g. the
        Foxglove scene channels (``foxglove.SceneUpdate``, ``protobuf``); chunking and rotation as :meth:`write`."""
        now = self._clock()
        f = self._current(now)
        start = f.stream.tell()
        channel_id = self._raw_channel(f, topic, schema, message_encoding)
        self.raw_written += 1
        self._add(f, start, now, channel_id, log_time_ns, data, publish_time_ns, sequence, raw=True)

    def _add(
        self,
        f: _OpenFile,
        start: int,
        now: float,
        channel_id: int,
        log_time_ns: int,
        data: bytes,
        publish_ns: int,
        seq: int,
        raw: bool = False,
    ) -> None:
        """Add a message to the open chunk; count chunks the mcap writer closed; rotate or poll."""
        before = f.stream.tell()
        if before != start:
            self.chunks_written += 1
            f.chunk_opened_at = None
        f.writer.add_message(
            channel_id=channel_id,
            log_time=log_time_ns,
            data=data,
            publish_time=publish_ns,
            sequence=seq & 0xFFFFFFFF,
        )
        f.messages += 1
        if not raw:
            self.messages_written += 1
        if f.stream.tell() != before:  # the mcap writer closed a full chunk (this message is in it)
            self.chunks_written += 1
            f.chunk_opened_at = None
        elif f.chunk_opened_at is None:
            f.chunk_opened_at = now
        if self.rotate_size_bytes and f.stream.tell() >= self.rotate_size_bytes:
            self.finish()
        else:
            self.poll(now)

    def poll(self, now: float | None = None) -> None:
        """Close the open chunk once its oldest message is ``chunk_flush_s`` old; rotate a file that is due."""
        f = self._file
        if f is None:
            return
        now = self._clock() if now is None else now
        if self._duration_due(f, now):
            self.finish()
        elif f.chunk_opened_at is not None and now - f.chunk_opened_at >= self.chunk_flush_s:
            self.flush_chunk()

    def flush_chunk(self) -> None:
        """Close and write the open chunk now (no-op when it holds no message)."""
        f = self._file
        if f is None or f.chunk_opened_at is None:
            return
        f.writer.flush()  # mcap >= 1.2: finishes the chunk in progress and writes it
        f.chunk_opened_at = None
        self.chunks_written += 1

    def finish(self) -> Path | None:
        """Finalise the current file (last chunk, summary, footer, fsync); returns its path."""
        f = self._file
        if f is None:
            return None
        self._file = None
        try:
            if f.chunk_opened_at is not None:
                self.chunks_written += 1
            f.writer.finish()
        finally:
            f.stream.close(sync=True)
        self.files_written.append(f.path)
        return f.path

    def abandon(self) -> Path | None:
        """Close the current file without finishing it (after a write error); it stays readable up to its
        last complete chunk. The next message opens a new file."""
        f = self._file
        if f is None:
            return None
        self._file = None
        with contextlib.suppress(OSError):
            f.stream.close(sync=False)
        return f.path

    # ----- internals ----------------------------------------------------------------------------
    def _duration_due(self, f: _OpenFile, now: float) -> bool:
        return bool(self.rotate_duration_s) and now - f.opened_at >= self.rotate_duration_s

    def _new_path(self) -> tuple[Path, int]:
        """Create the next file exclusively inside out_dir; returns its path and open descriptor."""
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
        for _ in range(10_000):
            name = f"{self.prefix}_{stamp}_{self._next_index:03d}.mcap"
            self._next_index += 1
            path = self.out_dir / name
            if path.resolve().parent != self.out_dir:
                raise ValueError(f"refusing to write {path}: it resolves outside {self.out_dir}")
            try:
                fd = os.open(path, flags, 0o644)
            except FileExistsError:
                continue
            return path, fd
        raise FileExistsError(f"no free file name for prefix {self.prefix!r} in {self.out_dir}")

    def _open(self, now: float) -> _OpenFile:
        path, fd = self._new_path()
        stream = _DirectFile(fd)
        try:
            writer = Writer(
                cast(IO[Any], stream),
                chunk_size=self.chunk_size_bytes,
                compression=_COMPRESSION[self.compression],
            )
            writer.start(profile="", library=LIBRARY)
            if self.metadata:
                writer.add_metadata("fixstream.recorder", self.metadata)
        except BaseException:
            stream.close(sync=False)
            raise
        return _OpenFile(path=path, stream=stream, writer=writer, opened_at=now)

    def _schema_data(self, name: str) -> bytes:
        data = self._schema_cache.get(name)
        if data is None:
            data = json.dumps(json_schema(name), sort_keys=True, separators=(",", ":")).encode()
            self._schema_cache[name] = data
        return data

    def _raw_channel(self, f: _OpenFile, topic: str, schema: tuple[str, str, bytes], message_encoding: str) -> int:
        name, encoding, data = schema
        channel_id = f.channel_ids.get((topic, name))
        if channel_id is not None:
            return channel_id
        schema_id = f.schema_ids.get(name)
        if schema_id is None:
            schema_id = f.writer.register_schema(name=name, encoding=encoding, data=data)
            f.schema_ids[name] = schema_id
        channel_id = f.writer.register_channel(topic=topic, message_encoding=message_encoding, schema_id=schema_id)
        f.channel_ids[(topic, name)] = channel_id
        return channel_id

    def _channel(self, f: _OpenFile, topic: str, model: type[Message]) -> int:
        name = model.__name__
        channel_id = f.channel_ids.get((topic, name))
        if channel_id is not None:
            return channel_id
        schema_id = f.schema_ids.get(name)
        if schema_id is None:
            schema_id = f.writer.register_schema(
                name=SCHEMA_PREFIX + name, encoding=SCHEMA_ENCODING, data=self._schema_data(name)
            )
            f.schema_ids[name] = schema_id
        channel_id = f.writer.register_channel(
            topic=topic,
            message_encoding=MESSAGE_ENCODING,
            schema_id=schema_id,
            metadata={ENCODING_METADATA_KEY: codec.encoding_of(model)},
        )
        f.channel_ids[(topic, name)] = channel_id
        return channel_id
