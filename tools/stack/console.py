"""Compose-like output: every process line prefixed with its service name, runner events marked ``[up]``."""

from __future__ import annotations

import sys
import threading
from typing import TextIO

_COLORS = (36, 33, 32, 35, 34, 91, 96, 93, 92, 95, 94)


class Console:
    def __init__(self, stream: TextIO | None = None, width: int = 8, color: bool | None = None) -> None:
        self.stream = stream or sys.stdout
        self.width = width
        self.color = self.stream.isatty() if color is None else color
        self._lock = threading.Lock()
        self._colors: dict[str, int] = {}

    def register(self, name: str) -> None:
        self.width = max(self.width, len(name))
        self._colors.setdefault(name, _COLORS[len(self._colors) % len(_COLORS)])

    def _prefix(self, name: str) -> str:
        text = f"{name:<{self.width}} |"
        if self.color:
            return f"\x1b[{self._colors.get(name, 0)}m{text}\x1b[0m"
        return text

    def _write(self, text: str) -> None:
        with self._lock:
            self.stream.write(text + "\n")
            self.stream.flush()

    def line(self, name: str, text: str) -> None:
        """One output line of a service."""
        self._write(f"{self._prefix(name)} {text}")

    def event(self, text: str) -> None:
        """A runner event (start, ready, exit, stop)."""
        self._write(f"[up] {text}")
