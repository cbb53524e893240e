"""``fixstream echo [KEYEXPR]``: print every message on a key expression, decoded, one line each.

A line is ``<key> [<Model> t=<header.stamp_ns in s> seq=<header.seq>] <the message's other fields as JSON>``;
``--json`` prints ``{"key", "schema", "message"}`` objects instead. A payload that does not decode is printed
too (``<key> !! <reason>: <detail>``), never skipped.

``--field PATH`` prints only that field of each message: a dotted path into the message as its JSON shows it,
list items by index (``header.stamp_ns``, ``position_m.2`` or ``position_m[2]``, ``plots.0.range_m``).
Repeat it for several fields: one line per message, ``<key> <value>`` for one field, ``<key> path=value ...`` for
more (values as JSON); with ``--json``, ``{"key", "schema", "fields": {path: value}}``. A message that lacks a
field (another type on a wildcard) is skipped and does not count towards ``--count``; when no message had the
field, echo ends with a line on stderr naming it and the fields the messages have.

``--once`` stops after the first message, ``--count N`` after N, ``--timeout S`` after S seconds.

Exit status: 0 done (or stopped with Ctrl-C / SIGTERM); 3 ``--timeout`` passed before the ``--once`` /
``--count`` messages arrived; 2 a bad key expression, field path or an unreachable router.
"""

from __future__ import annotations

import argparse
import re
from typing import Any

from .common import add_zenoh_arguments, key_expr, seconds

#: one segment of a field path: a name or a list index
_SEGMENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*|\d+")


def field_path(text: str) -> tuple[str | int, ...]:
    """argparse ``type=``: ``a.b[2].c`` / ``a.b.2.c`` -> ``("a", "b", 2, "c")`` (bad syntax: a usage error)."""
    parts = re.sub(r"\[(\d+)\]", r".\1", text).removeprefix(".").split(".")
    if not all(_SEGMENT.fullmatch(p) for p in parts):
        raise argparse.ArgumentTypeError(f"not a field path: {text!r} (e.g. header.stamp_ns, position_m.0)")
    return tuple(int(p) if p.isdigit() else p for p in parts)


class MissingField(LookupError):
    """The message has no such field."""


def extract(obj: Any, path: tuple[str | int, ...]) -> Any:
    """The value at ``path`` in a JSON-like object (dicts and lists), or :class:`MissingField`."""
    for part in path:
        if isinstance(part, int) and isinstance(obj, list):
            found = -len(obj) <= part < len(obj)
        else:
            found = isinstance(part, str) and isinstance(obj, dict) and part in obj
        if not found:
            raise MissingField(part)
        obj = obj[part]
    return obj


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("key_expr", nargs="?", default="fixstream/**", type=key_expr, help="Zenoh key expression")
    parser.add_argument("--json", action="store_true", help="one JSON object per line (key, schema, message)")
    parser.add_argument(
        "--field",
        action="append",
        type=field_path,
        default=[],
        metavar="PATH",
        help="print only this field (dotted path, list items by index; repeatable)",
    )
    stop = parser.add_mutually_exclusive_group()
    stop.add_argument("--once", action="store_true", help="exit after the first message (= --count 1)")
    stop.add_argument("--count", type=int, default=0, help="exit after this many messages (0: no limit)")
    parser.add_argument("--timeout", type=seconds, default=0.0, help="exit after this many seconds (0: never)")
    add_zenoh_arguments(parser)


def _path_text(path: tuple[str | int, ...]) -> str:
    return ".".join(str(p) for p in path)


class Misses:
    """The messages ``--field`` skipped: per missing path, how many; per message type, its top-level fields."""

    def __init__(self) -> None:
        self.paths: dict[str, int] = {}
        self.fields_of: dict[str, list[str]] = {}

    def add(self, path: str, schema: str, message: dict[str, Any]) -> None:
        self.paths[path] = self.paths.get(path, 0) + 1
        self.fields_of.setdefault(schema, list(message))

    def hint(self) -> str:
        """One line: which field matched nothing and the fields the messages have."""
        paths = ", ".join(f"--field {p} ({n} message{'s' if n != 1 else ''})" for p, n in self.paths.items())
        have = "; ".join(f"{schema}: {', '.join(names)}" for schema, names in sorted(self.fields_of.items()))
        return f"no such field in the messages received: {paths}; their fields are {have}"


def format_line(
    key: str,
    payload: bytes,
    encoding: str,
    as_json: bool,
    fields: list[tuple[str | int, ...]] | None = None,
    misses: Misses | None = None,
) -> str | None:
    """The line to print for one sample; None when ``fields`` are asked and the message lacks one of them (noted
    in ``misses``)."""
    import json

    from shared import codec

    try:
        msg = codec.decode(payload, encoding)
    except codec.DecodeError as exc:
        if as_json:
            return json.dumps({"key": key, "error": exc.reason, "detail": exc.detail})
        return f"{key} !! {exc.reason}: {exc.detail}"
    schema = type(msg).__name__
    if fields:
        dumped = msg.model_dump(mode="json")
        values: dict[str, Any] = {}
        for p in fields:
            try:
                values[_path_text(p)] = extract(dumped, p)
            except MissingField:
                if misses is not None:
                    misses.add(_path_text(p), schema, dumped)
                return None
        if as_json:
            return json.dumps({"key": key, "schema": schema, "fields": values})
        if len(values) == 1:
            return f"{key} {json.dumps(next(iter(values.values())))}"
        return f"{key} " + " ".join(f"{p}={json.dumps(v)}" for p, v in values.items())
    if as_json:
        return json.dumps({"key": key, "schema": schema, "message": msg.model_dump(mode="json")})
    body = msg.model_dump_json(exclude={"header"})
    return f"{key} [{schema} t={msg.header.stamp_ns * 1e-9:.3f}s seq={msg.header.seq}] {body}"


def run(args: argparse.Namespace) -> int:
    import sys

    from . import exit_codes
    from .listen import Listener

    if args.count < 0 or args.timeout < 0:
        print("fixstream echo: --count and --timeout must be >= 0", file=sys.stderr)
        return exit_codes.USAGE
    wanted = 1 if args.once else args.count
    printed = 0
    misses = Misses()
    with Listener(args, args.key_expr) as listener:
        for sample in listener.samples(args.timeout):
            line = format_line(sample.key, sample.payload, sample.encoding, args.json, args.field, misses)
            if line is None:
                continue
            print(line, flush=True)
            printed += 1
            if wanted and printed >= wanted:
                return exit_codes.OK
        stopped = listener.stopped.is_set()
    if printed == 0 and misses.paths:
        print(f"fixstream echo: {misses.hint()}", file=sys.stderr)
    if wanted and not stopped:
        print(
            f"fixstream echo: {printed} of {wanted} messages on {args.key_expr} in {args.timeout:g} s", file=sys.stderr
        )
        return exit_codes.TIMEOUT
    return exit_codes.OK
