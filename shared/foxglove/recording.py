"""The Foxglove channels of a recording: :class:`shared.foxglove.convert.Converter` output written beside the
fixstream channels of an MCAP file (the recorder's :meth:`~services.recorder.writer.RotatingMcapWriter.write_raw`).

Schemas are the ``foxglove-sdk`` message classes' own (``foxglove.SceneUpdate``, ``foxglove.LocationFix``, ...,
encoding ``protobuf``: a FileDescriptorSet), so Foxglove shows the scene and the map without any set-up.
A message that fails to convert is counted and logged once per reason; it never stops the recording.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Any, Protocol

from schemas import Message

from .convert import Converter

log = logging.getLogger("fixstream.foxglove")

MESSAGE_ENCODING = "protobuf"


class RawWriter(Protocol):
    def write_raw(
        self,
        topic: str,
        schema: tuple[str, str, bytes],
        message_encoding: str,
        data: bytes,
        log_time_ns: int,
        publish_time_ns: int,
        sequence: int = 0,
    ) -> None: ...


def schema_of(message: Any) -> tuple[str, str, bytes]:
    """(name, encoding, data) of a ``foxglove.messages`` object's schema."""
    s = type(message).get_schema()
    return str(s.name), str(s.encoding), bytes(s.data)


class FoxgloveChannels:
    """Converts each written fixstream message and writes the result on the Foxglove topics."""

    def __init__(self, converter: Converter | None = None) -> None:
        self.converter = converter or Converter()
        self.written = 0
        self.errors: Counter[str] = Counter()
        self._schemas: dict[type, tuple[str, str, bytes]] = {}
        self._seq: Counter[str] = Counter()

    def write(self, writer: RawWriter, key: str, msg: Message, log_time_ns: int) -> None:
        try:
            converted = self.converter.convert(key, msg)
        except Exception as exc:  # a conversion bug must not cost the recording
            reason = f"{type(msg).__name__}: {type(exc).__name__}"
            if not self.errors[reason]:
                log.warning("foxglove: cannot convert %s on %s: %s", type(msg).__name__, key, exc)
            self.errors[reason] += 1
            return
        for c in converted:
            schema = self._schemas.get(type(c.message))
            if schema is None:
                schema = self._schemas[type(c.message)] = schema_of(c.message)
            writer.write_raw(
                c.topic,
                schema,
                MESSAGE_ENCODING,
                c.message.encode(),
                log_time_ns,
                msg.header.stamp_ns,
                self._seq[c.topic],
            )
            self._seq[c.topic] += 1
            self.written += 1


__all__ = ["MESSAGE_ENCODING", "FoxgloveChannels", "schema_of"]
