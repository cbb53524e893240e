"""The plugin of this folder: what it offers the stack (shared.plugins; registered in pyproject.toml)."""

from shared.plugins import Plugin

PLUGIN = Plugin(
    name="terrain_nav",
    service="services.terrain_nav.service:build",
    simulators={"terrain_nav": "services.terrain_nav.simulator"},
    mc={"terrain_nav": "services.terrain_nav.mc"},
    summary="terrain-aided navigation, recurrent search over a hypothesis grid (digest 001)",
)
