"""The recorder's MCAP output: one file at a time, chunked, compressed, rotated, crash-safe, written by the Rust
MCAP writer inside ``foxglove-sdk`` (``foxglove.open_mcap``): 0.5–0.7 µs of CPU per 90-byte JSON message against
3.5–3.9 µs for the pure-Python ``mcap`` writer, zstd, measured in one run (docs/recorder.md).

Layout of every file (what Foxglove, ``@mcap/core`` and :mod:`shared.mcap_io` read):

* one schema per model: name ``fixstream.<Model>``, encoding ``jsonschema``, data = the model's JSON Schema
  (:func:`schemas.export.json_schema`);
* one channel per (key expression, model): topic = the key expression, message encoding ``json``, metadata
  ``zenoh_encoding`` = the wire encoding string;
* messages: data = the model's JSON; ``log_time`` = ``publish_time`` = ``header.stamp_ns`` (the data clock; the
  Rust writer puts the same value in both), ``sequence`` = a per-channel counter from 1;
* payloads that failed decoding or validation: topic ``fixstream/rejected/<original key>``, schema
  :data:`~shared.mcap_io.REJECTED_SCHEMA`, a JSON envelope holding the original bytes (base64), their Zenoh encoding,
  the reason and the wall time they arrived (:class:`~shared.mcap_io.Rejected`);
* metadata records and attachments (:meth:`RotatingMcapWriter.put_metadata`,
  :meth:`~RotatingMcapWriter.put_attachment`), written into the open file and again into every file after a rotation;
* zstd, lz4 or uncompressed chunks with message indexes; on :meth:`RotatingMcapWriter.finish` the summary (statistics,
  chunk indexes) and footer.

**Crash safety.** The file descriptor is wrapped in :class:`_DirectFile`, which hands every write straight to the
operating system (``os.write``; no user-space buffer), and the writer runs with ``disable_seeking``: a chunk is
built in memory and appended in one piece when it is closed, nothing already written is ever rewritten. A chunk is
closed when it reaches ``chunk_size_bytes`` (uncompressed) or, by :meth:`RotatingMcapWriter.poll`, once its oldest
message has waited ``chunk_flush_s`` of wall time (``MCAPWriter.flush()`` "finishes the current chunk and flushes
the underlying writer"). So a SIGKILL loses only what was written to the open chunk in the last ``chunk_flush_s``
(plus the time to the next poll) and at most ``chunk_size_bytes`` of it; everything before is in complete chunks,
which :func:`shared.mcap_io.iter_records` reads and :func:`shared.mcap_io.recover` (``fixstream info --recover``)
rewrites as a finalised file for readers that need the footer. Writes reach the page cache, which survives a process
crash; ``fsync`` is done when a file is finalised.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

import foxglove
from foxglove.mcap import MCAPCompression, MCAPWriteOptions

from schemas import Message
from schemas.export import json_schema
from shared import codec
from shared.mcap_io import (
    ENCODING_METADATA_KEY,
    MESSAGE_ENCODING,
    REJECTED_JSON_SCHEMA,
    REJECTED_SCHEMA,
    SCHEMA_ENCODING,
    SCHEMA_PREFIX,
    Rejected,
    encode_rejected,
)

Compression = Literal["zstd", "lz4", "none"]
_COMPRESSION: dict[str, MCAPCompression | None] = {
    "zstd": MCAPCompression.Zstd,
    "lz4": MCAPCompression.Lz4,
    "none": None,
}
LIBRARY = "fixstream-recorder"
log = logging.getLogger("fixstream.recorder")


class _DirectFile:
    """A write-only binary file with no user-space buffer: each ``write`` is handed to the OS at once.

    The Rust writer takes any object with ``write``, ``seek`` and ``flush``; with ``disable_seeking`` it only asks
    ``seek(0, SEEK_CUR)``. It writes whole records (a closed chunk and its message indexes, the summary), so the OS
    sees few, large writes. A failed write (disk full) is kept in :attr:`error` for the recorder to report, because
    the Rust side can only log it."""

    def __init__(self, fd: int) -> None:
        self._fd = fd
        self.pos = 0
        self.closed = False
        self.error: OSError | None = None

    def write(self, data: bytes | bytearray | memoryview) -> int:
        if self.closed:
            raise OSError("write to a closed recording file")
        view = memoryview(data).cast("B")
        total = len(view)
        try:
            while view:
                n = os.write(self._fd, view)
                if n <= 0:
                    raise OSError(f"os.write wrote {n} bytes")
                view = view[n:]
        except OSError as exc:
            self.error = self.error or exc
            raise
        self.pos += total
        return total

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        if (offset, whence) not in ((0, os.SEEK_CUR), (self.pos, os.SEEK_SET)):
            raise OSError(f"seek({offset}, {whence}) on an append-only recording file")
        return self.pos

    def tell(self) -> int:
        return self.pos

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
class _Attachment:
    media_type: str
    data: bytes
    log_time_ns: int


@dataclass
class _OpenFile:
    """The file being written and the channels declared in it."""

    path: Path
    stream: _DirectFile
    ctx: foxglove.Context
    writer: Any  # foxglove.mcap.MCAPWriter
    opened_at: float  # monotonic, s
    channels: dict[tuple[str, str], foxglove.Channel] = field(default_factory=dict)
    messages: int = 0
    #: monotonic time the oldest message not yet flushed was written (None: nothing unflushed)
    dirty_since: float | None = None


class RotatingMcapWriter:
    """Writes messages to ``<out_dir>/<prefix>_<UTC yyyymmddThhmmssZ>_<nnn>.mcap``, rotating by size or age.

    A file is opened on the first message after construction or rotation (no empty files), closed with its summary
    and footer by :meth:`finish` or a rotation. Rotation by size happens once the bytes written reach
    ``rotate_size_bytes`` (a file can exceed it by one chunk, the summary and the footer); rotation by duration once
    the file is ``rotate_duration_s`` old (checked on every write and poll). File names are generated here, never
    taken from the input, and must resolve inside ``out_dir``; an existing file is never overwritten (``O_EXCL``,
    ``O_NOFOLLOW``), the counter moves on instead.
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
        self._clock = clock
        self._file: _OpenFile | None = None
        self._next_index = 0
        self._schemas: dict[str, foxglove.Schema] = {}
        #: metadata records and attachments written into every file (name -> content)
        self.metadata: dict[str, dict[str, str]] = {"fixstream.recorder": dict(metadata)} if metadata else {}
        self.attachments: dict[str, _Attachment] = {}
        #: finalised files, oldest first (the last 1000)
        self.files_written: list[Path] = []
        self.files_finalised = 0
        #: fixstream messages written over all files
        self.messages_written = 0
        #: rejected payloads written (on fixstream/rejected/<key>)
        self.rejected_written = 0
        #: other messages (:meth:`write_raw`, e.g. the Foxglove channels) written over all files
        self.raw_written = 0
        #: chunks closed by :meth:`flush_chunk` (the writer also closes full chunks on its own)
        self.flushes = 0
        #: messages in chunks handed to the OS (what a SIGKILL cannot take any more)
        self.durable = 0
        self._unflushed = 0

    # ----- public API ---------------------------------------------------------------------------
    @property
    def current_path(self) -> Path | None:
        """The file being written, if any."""
        return self._file.path if self._file is not None else None

    @property
    def current_size_bytes(self) -> int:
        """Bytes of the current file handed to the OS."""
        return self._file.stream.pos if self._file is not None else 0

    @property
    def failed(self) -> OSError | None:
        """The write error of the current file, if a write to it failed."""
        return self._file.stream.error if self._file is not None else None

    @property
    def unflushed_age_s(self) -> float:
        """Wall time the oldest message not yet in a closed chunk has waited, s (0 if none)."""
        f = self._file
        return 0.0 if f is None or f.dirty_since is None else self._clock() - f.dirty_since

    def write(self, topic: str, msg: Message, rx_time_ns: int = 0) -> None:
        """Add one message on channel ``topic`` (the key expression), at its ``header.stamp_ns``. ``rx_time_ns``
        (the receive wall time) is accepted for the callers' convenience and not stored: see the module doc."""
        model = type(msg)
        self.write_json(topic, model, model.__pydantic_serializer__.to_json(msg), msg.header.stamp_ns)

    def write_json(self, topic: str, model: type[Message], data: bytes, stamp_ns: int) -> None:
        """Add a message already serialised as the model's JSON (the recorder's hot path)."""
        f = self._file if self._file is not None else self._current()
        if self.rotate_duration_s:
            f = self._current()
        ch = f.channels.get((topic, model.__name__))
        if ch is None:
            ch = self._model_channel(f, topic, model)
        ch.base.log(data, stamp_ns)
        self.messages_written += 1
        self._written(f)

    def write_rejected(self, rejected: Rejected, stamp_ns: int) -> None:
        """Record a payload that failed decoding or validation on ``fixstream/rejected/<key>``, at ``stamp_ns``."""
        f = self._current()
        topic = rejected.topic
        ch = f.channels.get((topic, REJECTED_SCHEMA))
        if ch is None:
            ch = self._declare(
                f,
                topic,
                REJECTED_SCHEMA,
                MESSAGE_ENCODING,
                self._schema(REJECTED_SCHEMA, SCHEMA_ENCODING, REJECTED_JSON_SCHEMA),
                {"original_key": rejected.key},
            )
        ch.base.log(encode_rejected(rejected), stamp_ns)
        self.rejected_written += 1
        self._written(f)

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
        Foxglove scene channels (``foxglove.SceneUpdate``, ``protobuf``). Its time in the file is ``publish_time_ns``
        (the data clock, as every message); ``log_time_ns`` and ``sequence`` are not stored (module doc)."""
        f = self._current()
        name, encoding, schema_data = schema
        ch = f.channels.get((topic, name))
        if ch is None:
            fschema = self._schemas.get(name)
            if fschema is None:
                fschema = self._schemas[name] = foxglove.Schema(name=name, encoding=encoding, data=schema_data)
            ch = self._declare(f, topic, name, message_encoding, fschema, None)
        ch.base.log(data, publish_time_ns)
        self.raw_written += 1
        self._written(f)

    def put_metadata(self, name: str, pairs: dict[str, str]) -> None:
        """A metadata record, written into the open file now and into every later file (same name: replaced)."""
        self.metadata[name] = dict(pairs)
        if self._file is not None and pairs:
            self._file.writer.write_metadata(name, dict(pairs))

    def put_attachment(self, name: str, media_type: str, data: bytes, log_time_ns: int) -> None:
        """An attachment (e.g. the scenario YAML), written into the open file now and into every later file."""
        att = _Attachment(media_type, bytes(data), log_time_ns)
        self.attachments[name] = att
        if self._file is not None:
            self._attach(self._file, name, att)

    def poll(self, now: float | None = None) -> None:
        """Close the open chunk once its oldest message is ``chunk_flush_s`` old; rotate a file that is due."""
        f = self._file
        if f is None:
            return
        now = self._clock() if now is None else now
        if self._duration_due(f, now) or (self.rotate_size_bytes and f.stream.pos >= self.rotate_size_bytes):
            self.finish()
        elif f.dirty_since is not None and now - f.dirty_since >= self.chunk_flush_s:
            self.flush_chunk()

    def flush_chunk(self) -> None:
        """Close and write the open chunk now (no-op when nothing is unflushed)."""
        f = self._file
        if f is None or f.dirty_since is None:
            return
        f.writer.flush()  # finishes the chunk in progress and hands it to _DirectFile (the OS)
        f.dirty_since = None
        self.flushes += 1
        self.durable += self._unflushed
        self._unflushed = 0

    def finish(self) -> Path | None:
        """Finalise the current file (last chunk, summary, footer, fsync); returns its path."""
        f = self._file
        if f is None:
            return None
        self._file = None
        try:
            f.writer.close()
        finally:
            self._release(f)
            f.stream.close(sync=True)
        self.durable += self._unflushed
        self._unflushed = 0
        self.files_finalised += 1
        self.files_written = [*self.files_written[-999:], f.path]
        return f.path

    def abandon(self) -> Path | None:
        """Close the current file without finishing it (after a write error); it stays readable up to its last
        complete chunk (``fixstream info --recover`` finalises it). The next message opens a new file."""
        f = self._file
        if f is None:
            return None
        self._file = None
        self._unflushed = 0
        with contextlib.suppress(OSError):
            f.stream.close(sync=False)
        with contextlib.suppress(Exception):  # the writer's last writes go to a closed file: refused, logged
            f.writer.close()
        self._release(f)
        return f.path

    # ----- internals ----------------------------------------------------------------------------
    def _written(self, f: _OpenFile) -> None:
        f.messages += 1
        self._unflushed += 1
        if f.dirty_since is None:
            f.dirty_since = self._clock()
        if self.rotate_size_bytes and f.stream.pos >= self.rotate_size_bytes:
            self.finish()

    def _current(self) -> _OpenFile:
        """The file to write to now: the open one, or a new one once rotation by duration is due."""
        f = self._file
        if f is not None and self._duration_due(f, self._clock()):
            self.finish()
            f = None
        if f is None:
            f = self._file = self._open(self._clock())
        return f

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
            ctx = foxglove.Context()
            options = MCAPWriteOptions(
                compression=_COMPRESSION[self.compression],
                profile="",
                chunk_size=self.chunk_size_bytes,
                disable_seeking=True,  # chunks are appended whole: nothing on disk is rewritten (crash safety)
                compression_threads=0,  # compress on the writing thread: the recorder runs on two shared cores
            )
            writer = foxglove.open_mcap(stream, context=ctx, writer_options=options)
        except BaseException:
            stream.close(sync=False)
            raise
        f = _OpenFile(path=path, stream=stream, ctx=ctx, writer=writer, opened_at=now)
        for name, pairs in self.metadata.items():
            if pairs:
                writer.write_metadata(name, dict(pairs))
        for name, att in self.attachments.items():
            self._attach(f, name, att)
        return f

    @staticmethod
    def _attach(f: _OpenFile, name: str, att: _Attachment) -> None:
        f.writer.attach(
            log_time=att.log_time_ns, create_time=time.time_ns(), name=name, media_type=att.media_type, data=att.data
        )

    def _release(self, f: _OpenFile) -> None:
        """Forget the file's channels (the SDK keeps a module-level table of Python channels by id)."""
        from foxglove import channel as _channel_module

        table = getattr(_channel_module, "_channels_by_id", None)
        for ch in f.channels.values():
            with contextlib.suppress(Exception):
                ch.close()
            if isinstance(table, dict):
                table.pop(ch.id(), None)
        f.channels.clear()

    def _schema(self, name: str, encoding: str, doc: dict[str, Any]) -> foxglove.Schema:
        s = self._schemas.get(name)
        if s is None:
            data = json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()
            s = self._schemas[name] = foxglove.Schema(name=name, encoding=encoding, data=data)
        return s

    def _model_channel(self, f: _OpenFile, topic: str, model: type[Message]) -> foxglove.Channel:
        name = model.__name__
        schema = self._schemas.get(SCHEMA_PREFIX + name) or self._schema(
            SCHEMA_PREFIX + name, SCHEMA_ENCODING, json_schema(name)
        )
        return self._declare(
            f, topic, name, MESSAGE_ENCODING, schema, {ENCODING_METADATA_KEY: codec.encoding_of(model)}
        )

    @staticmethod
    def _declare(
        f: _OpenFile,
        topic: str,
        key: str,
        message_encoding: str,
        schema: foxglove.Schema,
        metadata: dict[str, str] | None,
    ) -> foxglove.Channel:
        ch = foxglove.Channel(topic, schema=schema, message_encoding=message_encoding, context=f.ctx, metadata=metadata)
        f.channels[(topic, key)] = ch
        return ch
