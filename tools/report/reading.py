"""Read a recording for the report: every fixstream message of one or more MCAP files, decoded, with progress.

A report is of one recording: a file, or the rotated files of one recorder run; a directory means its newest
recording (:func:`select_recording`; ``--all`` merges several, and says so on the page). Records on channels
that are not fixstream's (the Foxglove scene and map channels the recorder adds, ``foxglove.*`` schemas) are
counted and skipped. Anything else that is wrong raises :class:`ReportError`
naming the file (and topic) and the problem:

* a missing, empty, non-MCAP or corrupt file (:class:`shared.mcap_io.McapReadError`);
* a message that does not decode to its model (its topic, the field and why);
* a **truncated** file — one that does not end with the MCAP footer and magic, as a recorder killed mid-write
  leaves it. Its complete chunks are readable, so ``allow_truncated=True`` reports them instead (with a note).

A finalised file goes through the fast path (:mod:`.fastread`); any file it does not take — truncated, corrupt,
holding an invalid message — is read by :mod:`shared.mcap_io`, which gives the errors above. The garbage
collector is paused while the messages are created (they form no cycles; it would only rescan them).
"""

from __future__ import annotations

import gc
import os
import re
import sys
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from schemas import Message, ScenarioMarker
from services.player.simulators import Event
from shared.mcap_io import MAGIC, SCHEMA_PREFIX, McapReadError, decode_record, iter_records, recording_files
from shared.service import PLAYER_PREFIX

#: builds an Event without NamedTuple's argument parsing (the read loop makes hundreds of thousands)
_new_event = tuple.__new__


class ReportError(RuntimeError):
    """A recording (or a scenario) the report cannot use; ``str()`` says which file and what is wrong."""


#: one decoded message of the recording: (``header.stamp_ns``, key = the MCAP topic, message)
Item = Event


@dataclass
class Recording:
    """Every fixstream message of the files, in file order, and what was skipped."""

    files: list[Path]
    items: list[Item] = field(default_factory=list)
    #: records on non-fixstream channels (schema name -> count), e.g. the Foxglove channels
    foreign: Counter[str] = field(default_factory=Counter)
    #: notes for the reader (truncated files read anyway, several scenario runs, ...)
    notes: list[str] = field(default_factory=list)

    @property
    def markers(self) -> list[tuple[str, ScenarioMarker]]:
        """The players' scenario markers: only a ``player/...`` source opens or ends a run, as for the services and
        the recorder (docs/recorder.md); a marker from anyone else names no run and no scenario (a new user's
        audit: a report counted 25 runs in a recording of 8, from the start markers of a non-player source)."""
        return [
            (it.key, it.msg)
            for it in self.items
            if isinstance(it.msg, ScenarioMarker) and it.msg.header.source.startswith(PLAYER_PREFIX)
        ]


#: the recorder's file names: ``<prefix>_<UTC yyyymmddThhmmssZ>_<nnn>.mcap`` (services/recorder/writer.py)
_RECORDER_NAME = re.compile(r"^(?P<prefix>.+)_(?P<stamp>\d{8}T\d{6}Z)_(?P<index>\d{3,})\.mcap$")


def recordings(files: Sequence[Path]) -> list[list[Path]]:
    """The files grouped into recordings, in the order given (a directory's: name order = time order).

    One recorder run writes ``<prefix>_<stamp>_<nnn>.mcap`` with ``nnn`` counting up over its rotated files and
    starting again at 000 in the next run; so a file continues the previous one's recording when it has the same
    prefix and the next index. Any other file (another prefix, index 000 again, a name not the recorder's) starts a
    recording of its own."""
    groups: list[list[Path]] = []
    last: tuple[str, int] | None = None
    for f in files:
        m = _RECORDER_NAME.match(f.name)
        here = (m["prefix"], int(m["index"])) if m else None
        if groups and here is not None and last is not None and here == (last[0], last[1] + 1):
            groups[-1].append(f)
        else:
            groups.append([f])
        last = here
    return groups


def _describe(group: list[Path]) -> str:
    size = sum(f.stat().st_size for f in group if f.exists())
    parts = f" (+{len(group) - 1} rotated file(s))" if len(group) > 1 else ""
    return f"{group[0].name}{parts}, {size / 1e6:.1f} MB"


def input_files(paths: Sequence[str | os.PathLike[str]], *, merge: bool = False) -> list[Path]:
    """The MCAP files of the one recording named (see :func:`select_recording`; notes are dropped)."""
    return select_recording(paths, merge=merge)[0]


def select_recording(paths: Sequence[str | os.PathLike[str]], *, merge: bool = False) -> tuple[list[Path], list[str]]:
    """(files, notes): the files of ONE recording unless ``merge`` (``--all``).

    * a file: that file; several files: they must be the rotated parts of one recording (:func:`recordings`),
      else :class:`ReportError` listing the recordings they are;
    * a directory: its newest recording (the last in name order, the recorder's names being time-stamped), with
      a note naming the others; with ``merge``, every file of the directory.
    """
    given: list[Path] = []
    notes: list[str] = []
    for raw in paths:
        p = Path(raw)
        if p.is_dir():
            found = recording_files(p)
            if not found:
                raise ReportError(f"{p}: no .mcap file in this directory")
            groups = recordings(found)
            if len(groups) > 1 and not merge:
                older = "; ".join(_describe(g) for g in reversed(groups[:-1]))
                notes.append(
                    f"{p} holds {len(groups)} recordings: reported the newest, {_describe(groups[-1])}; "
                    f"not reported: {older} (name a file, or --all to merge them)"
                )
                found = groups[-1]
            given += found
        elif not p.exists():
            raise ReportError(f"{p}: no such file or directory")
        else:
            given.append(p)
    if not given:
        raise ReportError("no recording given")
    groups = recordings(given)
    if len(groups) > 1 and not merge:
        listed = "; ".join(_describe(g) for g in groups)
        raise ReportError(
            f"{len(groups)} recordings given ({listed}): a report is of one recording; "
            "name one, or --all to merge them into one report"
        )
    if merge and len(groups) > 1:
        notes.append(f"{len(groups)} recordings merged into this report (--all): " + "; ".join(map(_describe, groups)))
    return given, notes


def is_finalised(path: Path) -> bool:
    """True if the file ends with the MCAP magic (its writer finished it: summary, footer, magic)."""
    try:
        size = path.stat().st_size
        if size < 2 * len(MAGIC):
            return False
        with path.open("rb") as f:
            f.seek(size - len(MAGIC))
            return f.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def read_recording(
    paths: Sequence[str | os.PathLike[str]],
    *,
    allow_truncated: bool = False,
    progress: bool = True,
    merge: bool = False,
) -> Recording:
    """Decode every fixstream message of the recording (see the module doc for what raises)."""
    from tqdm import tqdm

    files = input_files(paths, merge=merge)
    rec = Recording(files=files)
    gc_was_enabled = gc.isenabled()
    gc.disable()  # hundreds of thousands of new objects and no cycles: the collector would only rescan them
    try:
        with tqdm(desc="reading", unit=" msg", unit_scale=True, file=sys.stderr, disable=not progress) as bar:
            for path in files:
                bar.set_postfix_str(path.name)
                if is_finalised(path) and _read_fast(path, rec, bar):
                    continue
                _read_checked(path, rec, bar, allow_truncated)
    finally:
        if gc_was_enabled:
            gc.enable()
    return rec


def _read_fast(path: Path, rec: Recording, bar: Any) -> bool:
    """The fast path (:mod:`.fastread`) for a finalised file; False if the file needs the checked reader."""
    from .fastread import Fallback, read_messages

    items: list[Event] = []
    foreign: Counter[str] = Counter()
    append = items.append

    def on_message(topic: str, msg: Message) -> None:
        append(_new_event(Event, (msg.header.stamp_ns, topic, msg)))
        if len(items) % 8192 == 0:
            bar.update(8192)

    try:
        read_messages(path, on_message, lambda name: foreign.update((name,)))
    except (Fallback, OSError):
        bar.update(-(len(items) - len(items) % 8192))
        return False
    bar.update(len(items) % 8192 + sum(foreign.values()))
    rec.items += items
    rec.foreign.update(foreign)
    return True


def _read_checked(path: Path, rec: Recording, bar: Any, allow_truncated: bool) -> None:
    """:mod:`shared.mcap_io`: any file, with its precise errors; truncated files per ``allow_truncated``."""
    n_before = len(rec.items)
    pending = 0
    try:
        for record in iter_records(path):
            pending += 1
            if pending == 4096:
                bar.update(pending)
                pending = 0
            if not record.schema_name.startswith(SCHEMA_PREFIX):
                rec.foreign[record.schema_name or f"<no schema> ({record.message_encoding})"] += 1
                continue
            try:
                msg = decode_record(record)
            except McapReadError as exc:
                raise ReportError(
                    f"{path}: message on {exc.where} (log time {record.log_time_ns} ns): {exc.problem}"
                ) from None
            rec.items.append(_new_event(Event, (msg.header.stamp_ns, record.topic, msg)))
    except McapReadError as exc:
        raise ReportError(str(exc)) from None
    bar.update(pending)
    if not is_finalised(path):
        n = len(rec.items) - n_before
        what = (
            f"{path}: truncated: the file does not end with the MCAP footer and magic (a recorder that was "
            f"killed, or a copy cut short); {n} messages are readable up to its last complete chunk"
        )
        if not allow_truncated:
            raise ReportError(what + "; --allow-truncated reports them")
        rec.notes.append(what + ", reported")


__all__ = [
    "Item",
    "Recording",
    "ReportError",
    "input_files",
    "is_finalised",
    "read_recording",
    "recordings",
    "select_recording",
]
