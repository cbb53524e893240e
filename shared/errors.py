"""Exceptions shared by pure cores and service adapters (no Zenoh import here)."""

from __future__ import annotations


class InputRejected(ValueError):
    """Raised by a handler or core for an input it refuses; the service reports it and carries on."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail


class StartupError(RuntimeError):
    """A process cannot start (unreachable router, missing or invalid setting, bad argument): the command line
    prints the message as one line and exits with code 2."""


class ConnectError(StartupError):
    """No Zenoh router answered on the configured endpoints within the connect timeout."""
