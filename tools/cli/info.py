"""``fixstream info FILE.mcap``: what a recording holds, like ``ros2 bag info``.

Prints the file's state (finalised, or truncated by a crash and readable up to its last complete chunk), its
duration on the data clock (every message's time is its ``header.stamp_ns``), messages per key with their rate
(messages per second of data clock), schemas, compression, the metadata records (fixstream version, scenario, seed,
run index, services and their configuration) and the attachments (the scenario YAML, its maps).

``--recover`` rewrites a truncated file as a finalised one beside it (``<name>.recovered.mcap``, or ``--out``):
every message of its complete chunks, its metadata and attachments, then the summary and footer, so that readers
that need the footer (the ``mcap`` package's ``make_reader``, Foxglove, ``@mcap/core``'s indexed reader) open it.
Exit status: 0 done, 1 the recovered file could not be written, 2 not a readable MCAP file or bad arguments.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

#: stamps below this are on a scenario clock (s from 0), above it on the UNIX clock (printed as UTC)
_EPOCH_LIKE_NS = 10**17


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("files", nargs="+", metavar="FILE", help="MCAP recording(s)")
    parser.add_argument("--json", action="store_true", help="print one JSON document per file instead of text")
    parser.add_argument(
        "--recover",
        action="store_true",
        help="rewrite a truncated file as a finalised one (<name>.recovered.mcap beside it, or --out)",
    )
    parser.add_argument("--out", help="with --recover and one FILE: where the recovered file goes (must not exist)")
    parser.add_argument("--all-metadata", action="store_true", help="print every metadata value in full")


def run(args: argparse.Namespace) -> int:
    from shared.mcap_io import McapReadError, recover, scan

    if args.out and (not args.recover or len(args.files) != 1):
        print("fixstream info: --out needs --recover and exactly one FILE", file=sys.stderr)
        return 2
    status = 0
    for name in args.files:
        path = Path(name)
        try:
            result = scan(path)
        except McapReadError as exc:
            print(f"fixstream info: {exc}", file=sys.stderr)
            status = max(status, 2)
            continue
        if args.recover:
            if result.finalised:
                print(f"{path}: finalised already, nothing to recover")
            else:
                out = Path(args.out) if args.out else path.with_name(path.stem + ".recovered.mcap")
                try:
                    result = recover(path, out)
                except (OSError, McapReadError) as exc:
                    print(f"fixstream info: {path}: recovery to {out} failed: {exc}", file=sys.stderr)
                    status = max(status, 1)
                    continue
                print(f"{path}: recovered {result.messages} messages to {out}")
        print(json.dumps(as_dict(result)) if args.json else describe(result, args.all_metadata))
    return status


def _clock(ns: int) -> str:
    if ns >= _EPOCH_LIKE_NS:
        from datetime import UTC, datetime

        return datetime.fromtimestamp(ns / 1e9, UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")
    return f"{ns / 1e9:.3f} s"


def as_dict(s: Any) -> dict[str, Any]:
    """The scan as plain JSON types (``--json``)."""
    return {
        "path": str(s.path),
        "size_bytes": s.size,
        "state": "finalised" if s.finalised else "truncated",
        "tail_bytes": s.tail_bytes,
        "library": s.library,
        "profile": s.profile,
        "compression": dict(s.compression),
        "chunks": s.chunks,
        "messages": s.messages,
        "start_ns": s.start_ns,
        "end_ns": s.end_ns,
        "duration_s": (s.end_ns - s.start_ns) / 1e9,
        "topics": {
            t: {
                "count": v.count,
                "rate_hz": v.rate_hz,
                "schema": v.schema_name,
                "schemas": dict(v.schemas) or {v.schema_name: v.count},
                "message_encoding": v.message_encoding,
                "first_ns": v.first_ns,
                "last_ns": v.last_ns,
            }
            for t, v in sorted(s.topics.items())
        },
        "metadata": [{"name": m.name, "metadata": dict(m.metadata)} for m in s.metadata],
        "attachments": [
            {"name": a.name, "media_type": a.media_type, "size_bytes": len(a.data), "log_time_ns": a.log_time_ns}
            for a in s.attachments
        ],
    }


def describe(s: Any, all_metadata: bool = False) -> str:
    """The ``ros2 bag info``-like text of a scan."""
    from shared.mcap_io import REJECTED_PREFIX

    if s.finalised:
        state = "finalised (summary and footer written)"
    else:
        state = (
            f"TRUNCATED: not finalised, {s.tail_bytes} bytes after the last complete record; every message of the "
            "complete chunks is listed (fixstream info --recover FILE writes a finalised copy)"
        )
    lines = [
        f"File:             {s.path} ({s.size / 1e6:.3f} MB)",
        f"State:            {state}",
        f"Library:          {s.library or '-'}",
        f"Compression:      {', '.join(f'{k} ({n} chunks)' for k, n in sorted(s.compression.items())) or 'none'}",
        f"Duration:         {(s.end_ns - s.start_ns) / 1e9:.3f} s on the data clock",
        f"Start:            {_clock(s.start_ns)}",
        f"End:              {_clock(s.end_ns)}",
        f"Messages:         {s.messages}",
    ]
    data = {t: v for t, v in s.topics.items() if not t.startswith(REJECTED_PREFIX)}
    rejected = {t: v for t, v in s.topics.items() if t.startswith(REJECTED_PREFIX)}
    width = max((len(t) for t in s.topics), default=5)
    lines.append(f"Topics ({len(data)}):")
    lines.append(f"  {'key':<{width}}  {'count':>9}  {'rate Hz':>9}  schema")
    for t, v in sorted(data.items()):
        models = ", ".join(f"{n} {name}" for name, n in v.schemas.items()) if v.schemas else v.schema_name
        lines.append(f"  {t:<{width}}  {v.count:>9}  {v.rate_hz:>9.2f}  {models} ({v.message_encoding})")
    if rejected:
        total = sum(v.count for v in rejected.values())
        lines.append(f"Rejected payloads: {total} on {len(rejected)} keys (kept byte for byte, replayed as they came)")
        for t, v in sorted(rejected.items()):
            lines.append(f"  {t:<{width}}  {v.count:>9}")
    schemas = sorted({name for v in s.topics.values() for name in (v.schemas or [v.schema_name])})
    lines.append(f"Schemas ({len(schemas)}): {', '.join(schemas)}")
    lines.append(f"Metadata ({len(s.metadata)}):")
    for m in s.metadata:
        lines.append(f"  {m.name}:")
        for k, v in m.metadata.items():
            text = v if all_metadata or len(v) <= 100 else v[:97] + "..."
            lines.append(f"    {k}: {text}")
    lines.append(f"Attachments ({len(s.attachments)}):")
    for a in s.attachments:
        lines.append(f"  {a.name}  {a.media_type}  {len(a.data)} bytes")
    return "\n".join(printable(line) for line in lines)


def printable(text: str) -> str:
    """``text`` with its control characters escaped (``\\x1b``): names, topics and metadata come from the file, and a
    hostile one's terminal escapes once recoloured and could overwrite this command's output."""
    return text if text.isprintable() else "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
