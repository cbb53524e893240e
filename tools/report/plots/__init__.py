"""The report's sections: ``build(data, metrics) -> list[Section]`` per module (see :mod:`.common`).

Which modules, in which order, comes from the plugins (``Plugin.report``, :class:`shared.plugins.ReportSection`):
each estimator's section in the order of its ``rank``, then :mod:`.generic` for every other publisher of plain
``Fix``/``Track`` messages. The modules here are the repository's estimators' sections (tools-level: matplotlib
and the report's data model, which a service folder may not import); an estimator installed from elsewhere names
its own.
"""

from __future__ import annotations

from shared.plugins import report_sections

#: the section of publishers with no section of their own (always last)
GENERIC = "tools.report.plots.generic"


def section_names() -> list[str]:
    """The section builders' module names in page order (imported by the caller: matplotlib loads there)."""
    return [sec.module for _, sec in report_sections()] + [GENERIC]


def drawing_order(names: list[str]) -> list[str]:
    """``names`` with the costliest sections (``ReportSection.cost``) first, for a balanced pool of workers."""
    cost = {sec.module: sec.cost for _, sec in report_sections()}
    return sorted(names, key=lambda m: -cost.get(m, 0))


def own_section_services() -> set[str]:
    """The services (plugin names) that have a section of their own."""
    return {name for name, _ in report_sections()}
