"""The plugin of this folder: what it offers the stack (shared.plugins; registered in pyproject.toml)."""

from shared.plugins import Plugin

PLUGIN = Plugin(
    name="coordinator",
    service="services.coordinator.service:build",
    mc={"coordinator": "services.coordinator.mc"},
    summary="the AUV group's base coordinator: beacon roles and departures (digest 002)",
)
