"""The plugin of this folder: what it offers the stack (shared.plugins; registered in pyproject.toml)."""

from shared.plugins import Plugin

PLUGIN = Plugin(
    name="pcl_tracker",
    service="services.pcl_tracker.service:build",
    simulators={"pcl_tracker": "services.pcl_tracker.simulator"},
    mc={"pcl_tracker": "services.pcl_tracker.mc"},
    summary="passive coherent locator tracker, one receiver-illuminator pair (digest 003)",
)
