"""The plugin of this folder: what it offers the stack (shared.plugins; registered in pyproject.toml)."""

from shared.plugins import Plugin

PLUGIN = Plugin(
    name="rd_nav",
    service="services.rd_nav.service:build",
    simulators={"rd_group": "services.rd_nav.simulator"},
    mc={"rd_nav": "services.rd_nav.mc"},
    summary="one AUV of a group, docked AUVs as range-difference beacons (digest 002)",
)
