"""The plugin of this folder: what it offers the stack (shared.plugins; registered in pyproject.toml)."""

from shared.plugins import Plugin, ReportSection

PLUGIN = Plugin(
    name="rd_nav",
    service="services.rd_nav.service:build",
    simulators={"rd_group": "services.rd_nav.simulator"},
    mc={"rd_nav": "services.rd_nav.mc"},
    summary="one AUV of a group, docked AUVs as range-difference beacons (digest 002)",
    views={"RdNavFix": "services.rd_nav.views:rd_fix"},
    # the plot module is tools-level (matplotlib, the report's data model): named, never imported, from here
    report=ReportSection(
        "tools.report.plots.rd_nav",
        rank=30,
        cost=1,
        title="AUV group navigation (RD-LBL)",
        paper="tools.report.paper:RD_NAV",
    ),
)
