"""One progress line on stderr, rewritten in place (``\\r``), at most a few times a second.

Shown when stderr is a terminal, or when asked (``--progress``), never mixed into stdout (which a script may read).
``--no-progress`` hides it on a terminal too.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from typing import TextIO

NS_PER_S = 1_000_000_000


def add_arguments(parser: argparse.ArgumentParser, what: str = "the progress line") -> None:
    """``--progress`` / ``--no-progress`` (``args.progress``: True, False or None), for :func:`wanted`."""
    show = parser.add_mutually_exclusive_group()
    show.add_argument(
        "--progress", action="store_true", default=None, help=f"draw {what} on stderr even when it is not a terminal"
    )
    show.add_argument("--no-progress", dest="progress", action="store_false", default=None, help=f"never draw {what}")


def wanted(flag: bool | None, stream: TextIO | None = None) -> bool:
    """``--progress`` (True), ``--no-progress`` (False) or neither (None: only on a terminal)."""
    stream = stream or sys.stderr
    if flag is not None:
        return flag
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


class ProgressLine:
    """``update(done, data_ns)`` redraws ``<label>: <done>[/<total>] messages (<p> %), <data> s of data, <wall> s``
    at most every ``interval_s``; ``finish()`` ends the line. A log record printed meanwhile first clears the line
    (the next update draws it again below the record), so log lines and the progress line do not run together."""

    def __init__(
        self,
        label: str,
        total: int | None = None,
        data_total_s: float | None = None,
        stream: TextIO | None = None,
        interval_s: float = 0.2,
    ) -> None:
        self.label = label
        self.total = total
        self.data_total_s = data_total_s
        self.stream = stream or sys.stderr
        self.interval_s = interval_s
        self._t0 = time.monotonic()
        self._next = 0.0
        self._width = 0
        self._drawn = False
        self._last: tuple[int, int] = (0, 0)
        self._handlers = list(logging.getLogger().handlers)
        for h in self._handlers:
            h.addFilter(self._clear_for_log)

    def _clear_for_log(self, record: logging.LogRecord) -> bool:
        if self._drawn:
            self.stream.write("\r" + " " * self._width + "\r")
            self.stream.flush()
            self._drawn = False
            self._width = 0
            self._next = 0.0  # redraw at the next update
        return True

    def update(self, done: int, data_ns: int) -> None:
        self._last = (done, data_ns)
        now = time.monotonic()
        if now >= self._next:
            self._next = now + self.interval_s
            self._draw(done, data_ns, now)

    def text(self, done: int, data_ns: int, now: float) -> str:
        data_s = data_ns / NS_PER_S
        if self.total:
            count = f"{done}/{self.total} messages ({100.0 * done / self.total:.0f} %)"
        elif self.data_total_s:
            count = f"{done} messages ({100.0 * min(data_s / self.data_total_s, 1.0):.0f} %)"
        else:
            count = f"{done} messages"
        of = f"/{self.data_total_s:.1f}" if self.data_total_s else ""
        return f"{self.label}: {count}, {data_s:.1f}{of} s of data in {now - self._t0:.1f} s"

    def _draw(self, done: int, data_ns: int, now: float) -> None:
        line = self.text(done, data_ns, now)
        pad = " " * max(self._width - len(line), 0)
        self._width = len(line)
        self.stream.write("\r" + line + pad)
        self.stream.flush()
        self._drawn = True

    def finish(self) -> None:
        """Draw the final state and end the line (nothing if nothing was ever drawn and nothing happened)."""
        for h in self._handlers:
            h.removeFilter(self._clear_for_log)
        if self._drawn or self._last[0]:
            self._draw(*self._last, time.monotonic())
            self.stream.write("\n")
            self.stream.flush()
