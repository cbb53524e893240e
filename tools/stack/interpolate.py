"""Compose-style variable interpolation and ``.env`` files.

Follows the Compose Specification (``docs.docker.com/reference/compose-file/interpolation``):

* ``$VAR`` and ``${VAR}``: the value, or an empty string (with a warning) when unset;
* ``${VAR:-default}``: ``default`` when VAR is unset *or empty*; ``${VAR-default}``: only when unset;
* ``${VAR:?err}``: an error when VAR is unset or empty; ``${VAR?err}``: only when unset;
* ``${VAR:+alt}``: ``alt`` when VAR is set and non-empty, else empty; ``${VAR+alt}``: when set;
* operands nest (``${A:-${B:-x}}``) and are only evaluated when used;
* ``$$`` is a literal ``$``; a ``$`` not followed by a name or ``{`` is kept as it is;
* a malformed ``${...}`` is an error.

Interpolation applies to the values of the parsed YAML tree, never to mapping keys.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

_NAME = re.compile(r"[_A-Za-z][_A-Za-z0-9]*")
_OPERATORS = (":-", ":?", ":+", "-", "?", "+")

Warn = Callable[[str], None]


class InterpolationError(ValueError):
    """A malformed expression or a missing required variable."""


def _ignore(_message: str) -> None:
    return None


def _matching_brace(text: str, start: int) -> int:
    """Index of the ``}`` closing the ``${`` whose body starts at ``start`` (nested ``${}`` and ``$$`` aware)."""
    depth = 1
    i = start
    while i < len(text):
        ch = text[i]
        if ch == "$" and i + 1 < len(text) and text[i + 1] in "${":
            if text[i + 1] == "{":
                depth += 1
            i += 2
            continue
        if ch == "}":
            depth -= 1
            if depth == 0:
                return i
        i += 1
    raise InterpolationError(f"invalid interpolation format in {text!r}: unterminated '${{'")


def _braced(body: str, env: Mapping[str, str], warn: Warn, whole: str) -> str:
    m = _NAME.match(body)
    if m is None:
        raise InterpolationError(f"invalid interpolation format in {whole!r}: bad variable name in '${{{body}}}'")
    name = m.group(0)
    rest = body[m.end() :]
    value = env.get(name)
    if not rest:
        if value is None:
            warn(f"the {name} variable is not set, defaulting to a blank string")
            return ""
        return value
    op = next((o for o in _OPERATORS if rest.startswith(o)), None)
    if op is None:
        raise InterpolationError(f"invalid interpolation format in {whole!r}: unsupported '${{{body}}}'")
    operand = rest[len(op) :]
    unusable = value is None or (op.startswith(":") and value == "")
    if op in (":-", "-"):
        return interpolate(operand, env, warn) if unusable else str(value)
    if op in (":+", "+"):
        return "" if unusable else interpolate(operand, env, warn)
    # required: ":?" or "?"
    if unusable:
        message = interpolate(operand, env, warn) if operand else ""
        state = "unset" if value is None else "empty"
        raise InterpolationError(f"required variable {name} is {state}" + (f": {message}" if message else ""))
    return str(value)


def interpolate(text: str, env: Mapping[str, str], warn: Warn = _ignore) -> str:
    """Expand compose variables in one string."""
    out: list[str] = []
    i = 0
    while i < len(text):
        j = text.find("$", i)
        if j < 0:
            out.append(text[i:])
            break
        out.append(text[i:j])
        nxt = text[j + 1] if j + 1 < len(text) else ""
        if nxt == "$":
            out.append("$")
            i = j + 2
        elif nxt == "{":
            end = _matching_brace(text, j + 2)
            out.append(_braced(text[j + 2 : end], env, warn, text))
            i = end + 1
        else:
            m = _NAME.match(text, j + 1)
            if m is None:
                out.append("$")
                i = j + 1
            else:
                name = m.group(0)
                if name not in env:
                    warn(f"the {name} variable is not set, defaulting to a blank string")
                out.append(env.get(name, ""))
                i = m.end()
    return "".join(out)


def interpolate_tree(node: Any, env: Mapping[str, str], warn: Warn = _ignore, path: str = "") -> Any:
    """Interpolate every string value of a parsed YAML tree (keys are left alone)."""
    if isinstance(node, str):
        try:
            return interpolate(node, env, warn)
        except InterpolationError as exc:
            raise InterpolationError(f"{path or '<root>'}: {exc}") from None
    if isinstance(node, dict):
        return {k: interpolate_tree(v, env, warn, f"{path}.{k}" if path else str(k)) for k, v in node.items()}
    if isinstance(node, list):
        return [interpolate_tree(v, env, warn, f"{path}[{n}]") for n, v in enumerate(node)]
    return node


_ESCAPES = {"n": "\n", "t": "\t", "r": "\r", '"': '"', "\\": "\\"}


def _unquote_double(raw: str) -> str:
    out: list[str] = []
    i = 0
    while i < len(raw):
        if raw[i] == "\\" and i + 1 < len(raw) and raw[i + 1] in _ESCAPES:
            out.append(_ESCAPES[raw[i + 1]])
            i += 2
        else:
            out.append(raw[i])
            i += 1
    return "".join(out)


def parse_env_file(path: Path, env: Mapping[str, str] | None = None, warn: Warn = _ignore) -> dict[str, str]:
    """Read a compose ``.env`` file: ``KEY=VALUE`` lines, ``#`` comments, optional ``export``.

    Unquoted and double-quoted values are interpolated (from ``env`` and the lines above);
    single-quoted values are literal; `` #`` starts a comment after an unquoted value.
    """
    result: dict[str, str] = {}
    base = dict(env or {})
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise InterpolationError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    for lineno, line in enumerate(text.splitlines(), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        if text.startswith("export "):
            text = text[len("export ") :].lstrip()
        key, sep, raw = text.partition("=")
        key = key.strip()
        if not sep or not _NAME.fullmatch(key):
            raise InterpolationError(f"{path}:{lineno}: expected KEY=VALUE, got {line!r}")
        raw = raw.strip()
        scope = {**base, **result}
        if len(raw) >= 2 and raw[0] == raw[-1] == "'":
            value = raw[1:-1]
        elif len(raw) >= 2 and raw[0] == raw[-1] == '"':
            value = interpolate(_unquote_double(raw[1:-1]), scope, warn)
        else:
            comment = re.search(r"\s#", raw)
            if comment:
                raw = raw[: comment.start()].rstrip()
            value = interpolate(raw, scope, warn)
        result[key] = value
    return result
