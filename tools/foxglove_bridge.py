"""The live bridge behind ``fixstream foxglove``: Zenoh samples to a Foxglove WebSocket server (foxglove-sdk).

Every sample on the key expression is decoded with the wire codec (:func:`shared.codec.decode`) and served

* as itself: a channel whose topic is its key (``fixstream/fix/terrain/tan1``), schema ``fixstream.<Model>``
  (``jsonschema``, the model's JSON Schema), JSON messages: the recorder's channels, topic for topic, so a layout
  made on a recording works live. Every key carries one model; should a publisher put a second model on a key, it
  gets a second channel of the same topic, as in the recorder's MCAP (one channel per key and model);
* converted (:class:`shared.foxglove.convert.Converter`): the same ``/foxglove/scene/<key>`` and
  ``/foxglove/location/<key>`` channels, schemas and conversion as the recorder's MCAP files.

Channels are created when their first message arrives (the server advertises them to connected clients then).
A sample that does not decode is counted and skipped. The samples are handled on one worker thread, in
arrival order, so the converter's state (the scenario from the start marker) needs no lock.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections import Counter
from typing import Any

from schemas import Message
from shared import codec
from shared.foxglove.convert import Converter

log = logging.getLogger("fixstream.foxglove")


class Bridge:
    """Serves fixstream messages on the Foxglove channels of one foxglove-sdk context (see the module doc)."""

    def __init__(self, converter: Converter | None = None, *, raw: bool = True, context: Any = None) -> None:
        self.converter = converter or Converter()
        self.raw = raw
        self.context = context
        self._raw: dict[tuple[str, str], Any] = {}
        self._typed: dict[str, Any] = {}
        self.published: Counter[str] = Counter()
        self.errors: Counter[str] = Counter()
        self._queue: queue.Queue[tuple[str, bytes, str, int] | None] = queue.Queue(maxsize=100_000)
        self._worker: threading.Thread | None = None

    # ----- the sample path ---------------------------------------------------------------------------------------
    def on_sample(self, key: str, payload: bytes, encoding: str) -> None:
        """Queue one Zenoh sample (called on Zenoh's threads); dropped and counted when the queue is full."""
        try:
            self._queue.put_nowait((key, payload, encoding, time.time_ns()))
        except queue.Full:
            self.errors["queue_full"] += 1

    def start(self) -> None:
        self._worker = threading.Thread(target=self._run, name="foxglove-bridge", daemon=True)
        self._worker.start()

    def stop(self, timeout: float = 5.0) -> None:
        if self._worker is not None:
            self._queue.put(None)
            self._worker.join(timeout)
            self._worker = None

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            key, payload, encoding, rx_ns = item
            try:
                msg = codec.decode(payload, encoding)
            except codec.DecodeError as exc:
                self.errors[exc.reason] += 1
                continue
            try:
                self.handle(key, msg, rx_ns)
            except Exception as exc:  # a conversion bug must not stop the bridge
                reason = f"{type(msg).__name__}: {type(exc).__name__}"
                if not self.errors[reason]:
                    log.warning("foxglove: %s on %s: %s", type(exc).__name__, key, exc)
                self.errors[reason] += 1

    # ----- channels --------------------------------------------------------------------------------------------
    def handle(self, key: str, msg: Message, log_time_ns: int) -> None:
        """Log one decoded message on its raw channel and its converted Foxglove channels."""
        if self.raw:
            self._raw_channel(key, type(msg)).log(msg.model_dump_json().encode(), log_time=log_time_ns)
            self.published[key] += 1
        for c in self.converter.convert(key, msg):
            channel = self._typed.get(c.topic)
            if channel is None:
                import foxglove.channels as fc

                cls = getattr(fc, f"{type(c.message).__name__}Channel")
                channel = self._typed[c.topic] = cls(c.topic, context=self.context)
            channel.log(c.message, log_time=log_time_ns)
            self.published[c.topic] += 1

    def _raw_channel(self, key: str, model: type[Message]) -> Any:
        found = self._raw.get((key, model.__name__))
        if found is not None:
            return found
        from foxglove import Channel, Schema

        from schemas.export import json_schema

        schema = Schema(
            name=f"fixstream.{model.__name__}",
            encoding="jsonschema",
            data=json.dumps(json_schema(model.__name__), sort_keys=True).encode(),
        )
        channel = Channel(
            key,
            schema=schema,
            message_encoding="json",
            context=self.context,
            metadata={"zenoh_encoding": codec.encoding_of(model)},
        )
        self._raw[(key, model.__name__)] = channel
        return channel


__all__ = ["Bridge"]
