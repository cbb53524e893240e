"""The plugin of this folder: what it offers the stack (shared.plugins; registered in pyproject.toml)."""

from shared.plugins import Plugin, ReportSection

PLUGIN = Plugin(
    name="terrain_nav",
    service="services.terrain_nav.service:build",
    simulators={"terrain_nav": "services.terrain_nav.simulator"},
    mc={"terrain_nav": "services.terrain_nav.mc"},
    summary="terrain-aided navigation, recurrent search over a hypothesis grid (digest 001)",
    views={"TerrainFix": "services.terrain_nav.views:terrain_fix"},
    # the plot module is tools-level (matplotlib, the report's data model): named, never imported, from here
    report=ReportSection(
        "tools.report.plots.terrain_nav",
        rank=10,
        cost=2,
        title="Terrain-aided navigation",
        paper="tools.report.paper:TERRAIN_NAV",
    ),
)
