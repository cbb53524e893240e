"""The plugin of this folder: what it offers the stack (shared.plugins; registered in pyproject.toml)."""

from shared.plugins import Plugin

PLUGIN = Plugin(
    name="attitude",
    service="services.attitude.service:build",
    simulators={"attitude": "services.attitude.simulator"},
    mc={"attitude": "services.attitude.mc"},
    summary="aircraft heading, pitch and roll from radar plots (digest 004)",
)
