"""The plugin of this folder: what it offers the stack (shared.plugins; registered in pyproject.toml)."""

from shared.plugins import Plugin

PLUGIN = Plugin(
    name="lbl_nav",
    service="services.lbl_nav.service:build",
    simulators={"lbl_nav": "services.lbl_nav.simulator"},
    mc={"lbl_nav": "services.lbl_nav.mc"},
    summary="LBL navigation with no prior position and sparse beacons (digest 000)",
)
