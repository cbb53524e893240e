"""Exceptions shared by pure cores and service adapters (no Zenoh import here)."""

from __future__ import annotations


class InputRejected(ValueError):
    """Raised by a handler or core for an input it refuses; the service reports it and carries on."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail
