"""One module per estimator: ``build(data, metrics) -> list[Section]`` (see :mod:`.common`)."""

from __future__ import annotations

from types import ModuleType


def section_modules() -> list[ModuleType]:
    """The section builders in report order (imported on first use: matplotlib loads here)."""
    from . import attitude, generic, lbl_nav, pcl_tracker, rd_nav, terrain_nav

    return [terrain_nav, lbl_nav, rd_nav, pcl_tracker, attitude, generic]
