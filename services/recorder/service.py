"""The recorder service: everything on a key expression to MCAP, with loss counting.

Every sample on ``key_expr`` (default ``fixstream/**``) is decoded and validated with
:func:`shared.codec.decode`. A payload that fails is never written: it is counted per reason and reported
on ``fixstream/diag/recorder/<instance>`` (:meth:`Service.reject`). A valid message is written to the
current MCAP file (:class:`~services.recorder.writer.RotatingMcapWriter`) and its ``header.seq`` is checked
per (key, ``header.source``): a jump forward is a ``seq_gap`` diagnostic (and adds the missing count to
``lost``), a jump backwards (or a repeat) is a ``seq_reset`` diagnostic (publisher restarted). Both are
reported, not rejected: the message itself is recorded.

With ``FIXSTREAM_RECORDER_FOXGLOVE=true`` every written message that carries positions (truth, fixes, tracks)
is also written as Foxglove scene and map messages (:mod:`shared.foxglove`), so the file opens in Foxglove
with a 3D scene and a map and no set-up; the frames and the geodetic origin come from the scenario the player's
start marker names (looked up in ``FIXSTREAM_RECORDER_SCENARIOS_DIR``).

Status (``fixstream/status/recorder/<instance>``) adds ``written``, ``lost``, ``seq_gaps``,
``seq_resets``, ``write_errors``, ``files_written`` (finalised files), ``recent_files`` (the last ten),
``current_file`` and ``chunks_written`` to the base counters. SIGTERM finalises the current file (summary
and footer); after a SIGKILL the file is readable up to its last complete chunk (see
:mod:`services.recorder.writer`).
"""

from __future__ import annotations

import logging
import os
from collections import Counter
from collections.abc import Iterable
from typing import Any, ClassVar, cast

from schemas import Message
from services.player.scenario import load_by_name
from shared import codec
from shared.foxglove.convert import Converter
from shared.foxglove.recording import FoxgloveChannels
from shared.service import Output, Service, Subscription
from shared.settings import ZenohSettings

from .settings import RecorderSettings
from .writer import RotatingMcapWriter

log = logging.getLogger("fixstream.recorder")


class RecorderService(Service):
    """Records a key expression to rotating MCAP files; see the module docstring."""

    name: ClassVar[str] = "recorder"

    def __init__(self, settings: RecorderSettings, zenoh_settings: ZenohSettings | None = None) -> None:
        super().__init__(settings, zenoh_settings)
        self.config = settings
        self.writer = RotatingMcapWriter(
            settings.out_dir,
            prefix=settings.file_prefix,
            compression=settings.compression,
            chunk_size_bytes=settings.chunk_size_bytes,
            chunk_flush_s=settings.chunk_flush_s,
            rotate_size_bytes=settings.rotate_size_bytes,
            rotate_duration_s=settings.rotate_duration_s,
            metadata={"recorder": self.source, "key_expr": settings.key_expr, "pid": str(os.getpid())},
        )
        #: messages lost according to the publishers' seq (sum of the gaps)
        self.lost = 0
        self.write_errors = 0
        #: next expected seq per (key, header.source)
        self._next_seq: dict[tuple[str, str], int] = {}
        self.seq_events: Counter[str] = Counter()
        #: the Foxglove scene and map channels (FIXSTREAM_RECORDER_FOXGLOVE), converted from what is written
        self.foxglove: FoxgloveChannels | None = None
        if settings.foxglove:
            self.foxglove = FoxgloveChannels(
                Converter(scenarios_dir=settings.scenarios_dir, scenario_loader=load_by_name)
            )

    # ----- Service hooks ------------------------------------------------------------------------
    def subscriptions(self) -> list[Subscription]:
        return [Subscription(key_expr=self.config.key_expr, raw_handler=self._on_sample)]

    def on_idle(self) -> Iterable[Output]:
        """Close a chunk that has waited ``chunk_flush_s``; rotate a file whose duration is over."""
        try:
            self.writer.poll()
        except OSError as exc:
            self._write_failed(self.config.key_expr, exc)
        return ()

    def on_stop(self) -> None:
        """Finalise the current file (summary, footer, fsync); the base drained the queue before."""
        path = self.writer.finish()
        if path is not None:
            log.info("%s: finalised %s", self.source, path)

    def status_extra(self) -> dict[str, Any]:
        current = self.writer.current_path
        return {
            "written": self.writer.messages_written,
            "lost": self.lost,
            "seq_gaps": self.seq_events["seq_gap"],
            "seq_resets": self.seq_events["seq_reset"],
            "write_errors": self.write_errors,
            "files_written": len(self.writer.files_written),
            "recent_files": [str(p) for p in self.writer.files_written[-10:]],
            "current_file": str(current) if current is not None else None,
            "chunks_written": self.writer.chunks_written,
            "foxglove_written": self.foxglove.written if self.foxglove is not None else None,
            "foxglove_errors": dict(self.foxglove.errors) if self.foxglove is not None else None,
        }

    # ----- sample path --------------------------------------------------------------------------
    def _on_sample(self, key: str, payload: bytes, encoding: str) -> None:
        """Decode (DecodeError propagates: the base rejects and reports it), write, check seq."""
        msg = codec.decode(payload, encoding)
        try:
            self.writer.write(key, msg, self.rx_time_ns)
            if self.foxglove is not None:
                self.foxglove.write(self.writer, key, msg, self.rx_time_ns)
        except OSError as exc:
            self._write_failed(key, exc)
            return
        self._check_seq(key, msg)

    def _check_seq(self, key: str, msg: Message) -> None:
        h = msg.header
        ident = (key, h.source)
        expected = self._next_seq.get(ident)
        self._next_seq[ident] = h.seq + 1
        if expected is None or h.seq == expected:
            return
        who = h.source or "<no source>"
        if h.seq > expected:
            missing = h.seq - expected
            self.lost += missing
            self._seq_diag(key, "seq_gap", f"{missing} lost on {key} from {who}: expected seq {expected}, got {h.seq}")
        else:
            self._seq_diag(
                key, "seq_reset", f"seq went back on {key} from {who}: expected {expected}, got {h.seq} (restart?)"
            )

    def _seq_diag(self, key: str, reason: str, detail: str) -> None:
        self.seq_events[reason] += 1
        log.debug("%s: %s", self.source, detail)
        self.report(key, reason, detail, count=self.seq_events[reason], counts=dict(self.seq_events))

    def _write_failed(self, key: str, exc: OSError) -> None:
        """A disk error: drop the current file (readable up to its last chunk) and report it."""
        self.write_errors += 1
        path = self.writer.abandon()
        log.error("%s: writing %s failed: %s", self.source, path, exc)
        self.reject(key, "write_error", f"{path}: {exc}")


def build() -> RecorderService:
    """The recorder configured from ``FIXSTREAM_RECORDER_*`` and ``FIXSTREAM_ZENOH_*``."""
    settings = cast(RecorderSettings, RecorderSettings.load())
    return RecorderService(settings)
