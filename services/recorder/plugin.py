"""The plugin of this folder: what it offers the stack (shared.plugins; registered in pyproject.toml)."""

from shared.plugins import Plugin

PLUGIN = Plugin(
    name="recorder",
    service="services.recorder.service:build",
    summary="every stream to MCAP",
)
