"""The plugin of this folder: what it offers the stack (shared.plugins; registered in pyproject.toml)."""

from shared.plugins import Plugin, ReportSection

PLUGIN = Plugin(
    name="pcl_tracker",
    service="services.pcl_tracker.service:build",
    simulators={"pcl_tracker": "services.pcl_tracker.simulator"},
    mc={"pcl_tracker": "services.pcl_tracker.mc"},
    summary="passive coherent locator tracker, one receiver-illuminator pair (digest 003)",
    views={"PclScanReport": "services.pcl_tracker.views:scan_report"},
    multi_views=frozenset({"PclScanReport"}),
    # the plot module is tools-level (matplotlib, the report's data model): named, never imported, from here
    report=ReportSection(
        "tools.report.plots.pcl_tracker",
        rank=40,
        cost=5,
        title="Passive coherent location tracker",
        paper="tools.report.paper:PCL_TRACKER",
    ),
)
