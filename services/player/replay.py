"""Replay an MCAP recording onto Zenoh.

Records go out in file order (the recorder's receive order), paced by their log times at ``rate`` times real time
(0: as fast as possible); in a fixstream recording the log time is the data stamp, so a replay at ``--rate 1`` takes
the scenario's own duration whatever rate it was recorded at, and a player's start marker restarts the pacing (a new
run's clock starts again; a start marker from another source does not). A gap in the log times longer than
``max_gap_s`` (60 s by default) is paced as ``max_gap_s`` and counted (``ReplayResult.gaps_shortened``): one record
stamped years ahead, which a recording may hold, once held a replay at ``--rate 1`` for as long. Each record goes
on its channel's topic (the key expression it was recorded from),
rebuilt as its pydantic model and re-encoded with :mod:`shared.codec`, so the bytes on the wire are those the
original publisher sent (headers are kept as recorded: source, seq, stamps). A payload the recorder rejected
(``fixstream/rejected/<key>``) goes back byte for byte on its original key with its original encoding. A record
that cannot be rebuilt (unknown fixstream schema, invalid data) or was recorded on a wildcard key expression (a put
there reached every input it matched; ``wildcard_key``) is skipped, logged and counted, never silently lost.

Left out on purpose, counted but not logged: records of keys the selection leaves out (by default everything but
the player's keys, :mod:`services.player.selection`; a rejected payload is selected by its original key) and
channels that are not fixstream streams (the recorder's Foxglove scene and map channels). ``progress`` is called
after every published record.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from schemas import ScenarioMarker
from shared import codec
from shared.recovery import Recovery
from shared.service import PLAYER_PREFIX

from .pacing import Pacer
from .publish import Publishers

log = logging.getLogger("fixstream.replay")

#: wall time a replay leaves between a start marker and the records before it, s:
#: less than a service's stray window (``Service.stray_window_s``, 0.5 s), so a run's own samples never look stray
START_MARKER_GAP_S = 0.25
#: the longest gap between two records' log times a replay paces, s of data time (longer ones are shortened to it)
MAX_REPLAY_GAP_S = 60.0


@dataclass
class ReplayResult:
    """Published records per topic, skipped records per reason (records that could not be replayed), records left
    out on purpose per reason (``not_selected``, ``foreign_channel``), and whether the file was played to its end."""

    published: dict[str, int]
    skipped: dict[str, int] = field(default_factory=dict)
    left_out: dict[str, int] = field(default_factory=dict)
    completed: bool = True
    wall_s: float = 0.0
    #: gaps in the log times longer than the replay's ``max_gap_s``, each paced as ``max_gap_s``
    gaps_shortened: int = 0
    #: bytes after the last complete record, not read: the file was cut short (a crashed writer) or is still being
    #: written (0 for a file whose data section ends properly)
    tail_bytes: int = 0

    @property
    def total(self) -> int:
        return sum(self.published.values())


def replay(
    session: zenoh.Session,
    path: str | Path,
    *,
    rate: float = 1.0,
    stop: threading.Event | None = None,
    select: Callable[[str], bool] | None = None,
    progress: Callable[[int, int], None] | None = None,
    recovery: Recovery | None = None,
    max_gap_s: float = MAX_REPLAY_GAP_S,
) -> ReplayResult:
    """Publish the records of ``path`` that ``select(topic)`` keeps (None: every fixstream record) on their topics;
    ``progress(records published, log-time ns since the first)`` after each. Raises ``mcap_io.McapReadError`` for an
    unreadable file. ``recovery``: the keys published with a cache (None: as the environment's
    :class:`ZenohSettings` says; shared/recovery.py). ``max_gap_s``: the longest gap between log times paced (module
    doc)."""
    from shared import mcap_io

    pacer = Pacer(rate, stop)
    pubs = Publishers(session, recovery)
    skipped: Counter[str] = Counter()
    left_out: Counter[str] = Counter()
    first_log_time: int | None = None
    n_published = 0
    completed = True
    last_log_time: int | None = None
    t0 = time.monotonic()
    last_put = -math.inf
    max_gap_ns = round(max_gap_s * 1e9)
    paced_ns = 0  # the data clock the pacer follows: the log times, with every gap shortened to max_gap_ns
    gaps_shortened = 0
    read = mcap_io.ReadProgress()
    try:
        for record in mcap_io.iter_records(path, read):
            if mcap_io.is_rejected(record):
                try:
                    raw = mcap_io.decode_rejected(record)
                except mcap_io.McapReadError as exc:
                    skipped[exc.reason] += 1
                    log.warning("skipping a record on %s: %s", record.topic, exc)
                    continue
                if select is not None and not select(raw.key):
                    left_out["not_selected"] += 1
                    continue
                if not raw.payload and raw.reason == "payload_too_large":
                    skipped["not_kept"] += 1  # the recorder kept only its size
                    log.info("skipping a record on %s: an oversize payload, of which only its size was kept", raw.key)
                    continue
                key, payload, encoding = raw.key, raw.payload, raw.encoding
            elif not record.schema_name.startswith(mcap_io.SCHEMA_PREFIX):
                left_out["foreign_channel"] += 1  # e.g. /foxglove/scene/...: not a fixstream stream
                continue
            elif select is not None and not select(record.topic):
                left_out["not_selected"] += 1
                continue
            else:
                try:
                    msg = mcap_io.decode_record(record)
                except Exception as exc:  # reported and counted; the rest of the file still plays
                    reason = getattr(exc, "reason", type(exc).__name__)
                    skipped[str(reason)] += 1
                    log.warning("skipping a record on %s at %d ns: %s", record.topic, record.log_time_ns, exc)
                    continue
                key, payload, encoding = record.topic, codec.encode(msg), codec.encoding_of(type(msg))
                if (
                    isinstance(msg, ScenarioMarker)
                    and msg.event == "start"
                    and msg.header.source.startswith(PLAYER_PREFIX)
                    and last_log_time is not None
                ):
                    pacer, last_log_time = Pacer(rate, stop), None  # a new run: its data clock starts again
                    # what came before the run reaches the services before its start marker, as it did live (the
                    # marker has a subscription of its own: at --rate 0 it could overtake them, and a service then
                    # took them inside the run instead of dropping them as strays)
                    time.sleep(max(0.0, START_MARKER_GAP_S - (time.monotonic() - last_put)))
            if "*" in key:  # a put on a key expression reaches every key it matches: no publisher of ours makes one
                skipped["wildcard_key"] += 1
                log.warning("skipping a record on %s: a wildcard key expression would reach every key it matches", key)
                continue
            if last_log_time is not None and record.log_time_ns < last_log_time:
                log.debug("log time goes backwards on %s (%d < %d ns)", record.topic, record.log_time_ns, last_log_time)
            if last_log_time is None:
                paced_ns = last_log_time = record.log_time_ns
            elif record.log_time_ns > last_log_time:
                gap = record.log_time_ns - last_log_time
                if gap > max_gap_ns:
                    gaps_shortened += 1
                    log.warning(
                        "log time jumps %.3g s ahead on %s: paced as %g s", gap / 1e9, record.topic, max_gap_ns / 1e9
                    )
                paced_ns += min(gap, max_gap_ns)
                last_log_time = record.log_time_ns
            if not pacer.wait(paced_ns):
                completed = False
                break
            pubs.put_bytes(key, payload, encoding)
            last_put = time.monotonic()
            n_published += 1
            if progress is not None:
                first_log_time = last_log_time if first_log_time is None else first_log_time
                progress(n_published, max(0, last_log_time - first_log_time))
    finally:
        pubs.close()
    wall_s = time.monotonic() - t0
    tail = 0 if not completed or read.footer else max(0, Path(path).stat().st_size - read.end)
    result = ReplayResult(dict(pubs.counts), dict(skipped), dict(left_out), completed, wall_s, gaps_shortened, tail)
    if tail:
        log.warning("%s ends in %d bytes of an incomplete record (cut short, or being written): not read", path, tail)
    log.info(
        "replayed %d records on %d topics from %s (skipped: %s; left out: %s) in %.2f s",
        result.total,
        len(result.published),
        path,
        ", ".join(f"{n} {r}" for r, n in sorted(skipped.items())) or "none",
        ", ".join(f"{n} {r}" for r, n in sorted(left_out.items())) or "none",
        result.wall_s,
    )
    return result
