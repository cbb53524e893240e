"""The plugin of this folder: what it offers the stack (shared.plugins; registered in pyproject.toml)."""

from shared.plugins import Plugin, ReportSection

PLUGIN = Plugin(
    name="attitude",
    service="services.attitude.service:build",
    simulators={"attitude": "services.attitude.simulator"},
    mc={"attitude": "services.attitude.mc"},
    summary="aircraft heading, pitch and roll from radar plots (digest 004)",
    views={"AttitudeEstimate": "services.attitude.views:attitude_estimate"},
    # the plot module is tools-level (matplotlib, the report's data model): named, never imported, from here
    report=ReportSection(
        "tools.report.plots.attitude",
        rank=50,
        cost=4,
        title="Aircraft attitude from radar",
        paper="tools.report.paper:ATTITUDE",
    ),
)
