"""The plugin of this folder: what it offers the stack (shared.plugins; registered in pyproject.toml)."""

from shared.plugins import Plugin

PLUGIN = Plugin(
    name="player",
    simulators={"nav_platform": "services.player.simulators.nav_platform"},
    summary="the scenario player's own simulators (fixstream play)",
)
