"""How ``fixstream --help`` reads: plain text from the modules' reStructuredText docstrings, every default shown.

The sub-commands' module docstrings are their ``--help`` descriptions. They are written for Sphinx-style readers
(````literal````, ``:func:`name```, ``*emphasis*``), so :func:`plain` turns them into plain text first, and
:class:`HelpFormatter` re-wraps their paragraphs to the terminal (keeping ``*`` and ``-`` bullets as items) and
appends ``(default: X)`` to every option whose help does not already name its default.
"""

from __future__ import annotations

import argparse
import re
import textwrap

#: ````literal```` spans: kept verbatim, only the backticks go
_LITERAL = re.compile(r"``(.+?)``", re.DOTALL)
#: ``:role:`text <target>```, ``:role:`~mod.Name```, ``:role:`name```
_ROLE = re.compile(r":[a-z]+(?::[a-z]+)?:`(~?)([^`<]+?)(?:\s*<[^`>]*>)?`")
#: ```interpreted text``` (single backticks)
_INTERPRETED = re.compile(r"`([^`]+)`")
#: ``**strong**`` and ``*emphasis*``: only around words, so ``fixstream/**`` stays as it is
_STRONG = re.compile(r"(?<![\w/*])\*\*(\w[^*]*?)\*\*(?![\w*])")
_EMPHASIS = re.compile(r"(?<![\w/*])\*(\w[^*]*?)\*(?![\w*])")
#: a line that starts an item of a list
_ITEM = re.compile(r"^\s*(?:[*\-]|\d+\.)\s+")


def _role(match: re.Match[str]) -> str:
    tilde, text = match.group(1), match.group(2).strip()
    return text.rsplit(".", 1)[-1] if tilde else text


def _prose(text: str) -> str:
    text = _ROLE.sub(_role, text)
    text = _INTERPRETED.sub(r"\1", text)
    text = _STRONG.sub(r"\1", text)
    return _EMPHASIS.sub(r"\1", text)


def plain(text: str) -> str:
    """reStructuredText inline markup to plain text: literals lose their backticks (their content is kept as is),
    roles become their text (``:func:`~a.b.c``` -> ``c``), emphasis loses its stars."""
    out: list[str] = []
    pos = 0
    for m in _LITERAL.finditer(text):
        out.append(_prose(text[pos : m.start()]))
        out.append(m.group(1))
        pos = m.end()
    out.append(_prose(text[pos:]))
    return "".join(out)


def _fill(text: str, width: int, indent: str) -> str:
    """Re-wrap each paragraph (blank-line separated) to ``width``; list items stay items, indented under their
    bullet."""
    paragraphs: list[str] = []
    for para in re.split(r"\n\s*\n", text.strip("\n")):
        items: list[str] = []
        for line in para.splitlines():
            if _ITEM.match(line) or not items:
                items.append(line.strip())
            else:
                items[-1] += " " + line.strip()
        filled = []
        for item in items:
            bullet = _ITEM.match(item)
            hang = " " * len(bullet.group(0)) if bullet else ""
            filled.append(
                textwrap.fill(item, width, initial_indent=indent, subsequent_indent=indent + hang) if item else indent
            )
        paragraphs.append("\n".join(filled))
    return "\n\n".join(paragraphs)


class HelpFormatter(argparse.HelpFormatter):
    """Paragraphs re-wrapped to the terminal and ``(default: X)`` after every option that has a default."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return _fill(text, max(width, 40), indent)

    def _get_help_string(self, action: argparse.Action) -> str | None:
        help_text = action.help or ""
        default = action.default
        if (
            "%(default)" in help_text
            or "default" in help_text.lower()
            or default is None
            or default is False
            or default == []
            or default is argparse.SUPPRESS
            or isinstance(action, argparse._HelpAction | argparse._VersionAction | argparse._SubParsersAction)
        ):
            return help_text
        if not action.option_strings and action.nargs not in (argparse.OPTIONAL, argparse.ZERO_OR_MORE):
            return help_text  # a required positional has no default to show
        return f"{help_text} (default: %(default)s)".lstrip()


def description_of(doc: str | None, fallback: str) -> str:
    """A module docstring as a ``--help`` description, in plain text."""
    return plain(doc.strip()) if doc and doc.strip() else fallback
