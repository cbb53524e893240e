"""The registry's answers for Foxglove views and report sections (shared.plugins; docs/architecture.md).

Plugins registered at run time (``register``) stand for ones installed from elsewhere: their converter is used
for their message type, two plugins may not both convert one type, a plugin registered later is seen at once
(the resolved converters are cached per type name), and the report's sections follow the plugins' ranks with the
generic section last.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from schemas import Depth, Header
from shared import plugins as registry
from shared.foxglove.frames import Estimate, FrameContext, estimates_of
from shared.plugins import Plugin, PluginError, ReportSection, register
from tools.report.plots import GENERIC, drawing_order, section_names

CTX = FrameContext()


def depth_as_fix(key: str, msg: Any, ctx: FrameContext) -> list[Estimate]:
    """A test converter: the depth as a fix straight below the origin."""
    return [Estimate("fix", "probe", "probe", msg.header.stamp_ns, np.array([0.0, 0.0, -msg.depth_m]))]


@pytest.fixture()
def restore() -> Iterator[None]:
    """Put the registry back as the entry points made it."""
    saved = dict(registry.plugins())
    yield
    registry.plugins().clear()
    registry.plugins().update(saved)
    registry._views.clear()
    registry.multi_view_types.cache_clear()


def test_a_registered_plugin_converts_its_type_and_is_seen_at_once(restore: None) -> None:
    msg = Depth(header=Header(stamp_ns=7), depth_m=12.5)
    assert estimates_of("fixstream/fix/probe/p1", msg, CTX) == []  # no plugin converts Depth yet (cached: None)
    register(Plugin(name="probe", views={"Depth": f"{__name__}:depth_as_fix"}))
    (e,) = estimates_of("fixstream/fix/probe/p1", msg, CTX)
    assert (e.kind, e.entity, e.stamp_ns) == ("fix", "probe", 7)
    assert e.position.tolist() == [0.0, 0.0, -12.5]


def test_two_plugins_may_not_convert_one_type(restore: None) -> None:
    register(Plugin(name="probe_a", views={"Depth": f"{__name__}:depth_as_fix"}))
    register(Plugin(name="probe_b", views={"Depth": f"{__name__}:depth_as_fix"}))
    with pytest.raises(PluginError, match="several plugins"):
        registry.view_converter("Depth")


def test_the_repository_estimators_convert_their_own_types() -> None:
    owners = {t: p.name for p in registry.plugins().values() for t in p.views}
    assert owners == {
        "TerrainFix": "terrain_nav",
        "LblFix": "lbl_nav",
        "RdNavFix": "rd_nav",
        "PclScanReport": "pcl_tracker",
        "AttitudeEstimate": "attitude",
    }
    assert registry.multi_view_types() == {"PclScanReport"}


def test_sections_follow_the_ranks_with_the_generic_one_last(restore: None) -> None:
    before = section_names()
    assert before[-1] == GENERIC
    assert before[:-1] == [
        f"tools.report.plots.{k}" for k in ("terrain_nav", "lbl_nav", "rd_nav", "pcl_tracker", "attitude")
    ]
    register(Plugin(name="probe", report=ReportSection("probe.report", rank=25, cost=9)))
    names = section_names()
    at = names.index("probe.report")  # rank 25: after lbl_nav (20), before rd_nav (30)
    assert names[at - 1 : at + 2] == ["tools.report.plots.lbl_nav", "probe.report", "tools.report.plots.rd_nav"]
    assert drawing_order(names)[0] == "probe.report"  # the costliest is started first
    assert sorted(drawing_order(names)) == sorted(names)
