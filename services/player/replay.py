"""Replay an MCAP recording onto Zenoh.

Records go out in log-time order, paced by log-time differences at ``rate`` times real time (0: as fast
as possible), each on its channel's topic (the key expression it was recorded from). Every record is
rebuilt as its pydantic model and re-encoded with :mod:`shared.codec`, so the bytes on the wire are
those the original publisher sent (headers are kept as recorded: source, seq, stamps). A record that
cannot be rebuilt (unknown schema, invalid data) is skipped, logged and counted, never silently lost.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from shared import codec

from .pacing import Pacer
from .publish import Publishers

log = logging.getLogger("fixstream.replay")


@dataclass
class ReplayResult:
    """Published records per topic, skipped records per reason, and whether the file was played to its end."""

    published: dict[str, int]
    skipped: dict[str, int] = field(default_factory=dict)
    completed: bool = True
    wall_s: float = 0.0

    @property
    def total(self) -> int:
        return sum(self.published.values())


def replay(
    session: zenoh.Session, path: str | Path, *, rate: float = 1.0, stop: threading.Event | None = None
) -> ReplayResult:
    """Publish every record of ``path`` on its topic. Raises ``mcap_io.McapReadError`` for an unreadable file."""
    from shared import mcap_io

    pacer = Pacer(rate, stop)
    pubs = Publishers(session)
    skipped: Counter[str] = Counter()
    completed = True
    last_log_time: int | None = None
    t0 = time.monotonic()
    try:
        for record in mcap_io.iter_records(path):
            try:
                msg = mcap_io.decode_record(record)
            except Exception as exc:  # reported and counted; the rest of the file still plays
                reason = getattr(exc, "reason", type(exc).__name__)
                skipped[str(reason)] += 1
                log.warning("skipping a record on %s at %d ns: %s", record.topic, record.log_time_ns, exc)
                continue
            if last_log_time is not None and record.log_time_ns < last_log_time:
                log.warning(
                    "log time goes backwards on %s (%d < %d ns)", record.topic, record.log_time_ns, last_log_time
                )
            last_log_time = record.log_time_ns if last_log_time is None else max(last_log_time, record.log_time_ns)
            if not pacer.wait(last_log_time):
                completed = False
                break
            pubs.put_bytes(record.topic, codec.encode(msg), codec.encoding_of(type(msg)))
    finally:
        pubs.close()
    result = ReplayResult(dict(pubs.counts), dict(skipped), completed, time.monotonic() - t0)
    log.info(
        "replayed %d records on %d topics from %s (%d skipped) in %.2f s",
        result.total,
        len(result.published),
        path,
        sum(skipped.values()),
        result.wall_s,
    )
    return result
