"""Diagnostics: what a service rejected, why, and how many times."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from .base import Message


class Diagnostic(Message):
    """A rejected input (or another notable event) reported by a service."""

    service: str = Field(min_length=1, max_length=64)
    instance: str = Field(min_length=1, max_length=128)
    level: Literal["info", "warning", "error"] = "warning"
    key: str = Field(max_length=1024, description="key expression the offending input arrived on")
    reason: str = Field(min_length=1, max_length=64, description="short machine-readable reason code")
    detail: str = Field(default="", max_length=4096)
    count: int = Field(ge=1, description="how many times this reason has occurred so far")
    counts: dict[str, int] = Field(default_factory=dict, description="running count of every reason")
