"""The plugin of this folder: what it offers the stack (shared.plugins; registered in pyproject.toml)."""

from shared.plugins import Plugin, ReportSection

PLUGIN = Plugin(
    name="lbl_nav",
    service="services.lbl_nav.service:build",
    simulators={"lbl_nav": "services.lbl_nav.simulator"},
    mc={"lbl_nav": "services.lbl_nav.mc"},
    summary="LBL navigation with no prior position and sparse beacons (digest 000)",
    views={"LblFix": "services.lbl_nav.views:lbl_fix"},
    # the plot module is tools-level (matplotlib, the report's data model): named, never imported, from here
    report=ReportSection(
        "tools.report.plots.lbl_nav",
        rank=20,
        cost=3,
        title="LBL navigation, sparse beacons",
        paper="tools.report.paper:LBL_NAV",
    ),
)
