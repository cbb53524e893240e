"""The plugin contract: how a process folder (an estimator, the recorder, ...) makes itself known to the stack.

Each folder ``services/<name>/`` exports one :class:`Plugin` object in ``services/<name>/plugin.py`` and
registers it as a package entry point in the group ``fixstream.plugins``::

    [project.entry-points."fixstream.plugins"]
    lbl_nav = "services.lbl_nav.plugin:PLUGIN"

That line, the folder and its compose service are all that adding an estimator takes: ``fixstream run <name>``,
the player's simulator kinds, ``fixstream mc``, the report's sections and the Foxglove views (recorder channels,
bridge) find it through :func:`plugins` (ROS 2 packages register their nodes the same way). Every part is named
by a dotted ``module:attribute`` path and imported only when used, so listing the plugins costs nothing and a
service process imports only its own code.

The registry is runtime: it reads entry points and imports what they name, and never names a service itself.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from importlib.metadata import entry_points
from typing import Any

from .errors import StartupError

#: what a view converter is called with and returns: (key, message, shared.foxglove.frames.FrameContext) ->
#: list[shared.foxglove.frames.Estimate] (typed loosely here: the registry does not import the Foxglove code)
ViewConverter = Callable[[str, Any, Any], list[Any]]

GROUP = "fixstream.plugins"


class PluginError(StartupError):
    """No plugin of that name, or one whose parts do not resolve."""


@dataclass(frozen=True)
class ReportSection:
    """An estimator's section of ``fixstream report``.

    ``module`` has ``build(data, metrics) -> list[Section]`` (``tools.report.plots.common``): a tools-level module
    (it draws with matplotlib on the report's data model), named by its dotted path so the plugin — a service-level
    object — never imports it. ``rank`` places the section on the page (lower first; the generic section of plain
    ``Fix``/``Track`` publishers comes after all of them); ``cost`` is a relative drawing time (higher is started
    first when the sections are drawn in parallel; it changes no output). ``title`` is the readable name of the
    kind in the summary table; ``paper`` names (``module:attribute``) the list of ``tools.report.paper.PaperFigure``
    the run is scored against (None: "no paper figure").
    """

    module: str
    rank: int = 100
    cost: int = 0
    title: str = ""
    paper: str | None = None


@dataclass(frozen=True)
class Plugin:
    """What one process folder offers the stack; every field but ``name`` is optional."""

    #: the name of ``fixstream run <name>`` and of the folder
    name: str
    #: ``module:function`` building the service from the environment (``build() -> Service``)
    service: str | None = None
    #: simulator kind -> module whose import registers it with the player (``@register(kind)``)
    simulators: dict[str, str] = field(default_factory=dict)
    #: estimator kind (as scenario files name it) -> module with ``run_core``/``aggregate`` for ``fixstream mc``
    mc: dict[str, str] = field(default_factory=dict)
    #: one line for ``fixstream run --list`` and the docs
    summary: str = ""
    #: message type name (``type(msg).__name__``) -> ``module:function`` turning such a message into Foxglove
    #: estimates (:data:`ViewConverter`; the generic ``Truth``, ``Fix`` and ``Track`` need none)
    views: dict[str, str] = field(default_factory=dict)
    #: those of its ``views`` types that carry any number of positions (a scan's tracks): their Foxglove map
    #: channel is ``foxglove.LocationFixes`` (one schema per topic), the others' ``foxglove.LocationFix``
    multi_views: frozenset[str] = frozenset()
    #: its section of ``fixstream report`` (None: its plain ``Fix``/``Track`` outputs get the generic one)
    report: ReportSection | None = None


def resolve(path: str) -> Any:
    """The object a ``module:attribute`` (or plain ``module``) path names."""
    module_name, _, attr = path.partition(":")
    module = importlib.import_module(module_name)
    return getattr(module, attr) if attr else module


@cache
def plugins() -> dict[str, Plugin]:
    """Every registered plugin by name (entry points of the installed distributions)."""
    found: dict[str, Plugin] = {}
    for ep in entry_points(group=GROUP):
        plugin = ep.load()
        if not isinstance(plugin, Plugin):
            raise PluginError(f"entry point {ep.name} = {ep.value} is not a shared.plugins.Plugin")
        if plugin.name != ep.name:
            raise PluginError(f"entry point {ep.name} names a plugin called {plugin.name!r}")
        found[plugin.name] = plugin
    return found


def register(plugin: Plugin) -> None:
    """Add a plugin at run time (tests, notebooks): the same effect as an entry point, for this process."""
    plugins()[plugin.name] = plugin
    _views.clear()
    multi_view_types.cache_clear()


def plugin(name: str) -> Plugin:
    try:
        return plugins()[name]
    except KeyError:
        raise PluginError(f"no plugin named {name!r}; installed: {', '.join(sorted(plugins()))}") from None


def simulator_modules() -> dict[str, str]:
    """Simulator kind -> the module that registers it, over every plugin."""
    return {kind: module for p in plugins().values() for kind, module in p.simulators.items()}


def mc_module(kind: str) -> str | None:
    """The ``fixstream mc`` module of an estimator kind, or None."""
    return next((p.mc[kind] for p in plugins().values() if kind in p.mc), None)


#: message type name -> its resolved view converter (None: no plugin converts it), filled on first use
_views: dict[str, ViewConverter | None] = {}


def view_converter(type_name: str) -> ViewConverter | None:
    """The converter a plugin declares for messages of this type (``Plugin.views``), or None; resolved once."""
    try:
        return _views[type_name]
    except KeyError:
        pass
    owners = [(p.name, p.views[type_name]) for p in plugins().values() if type_name in p.views]
    if len(owners) > 1:
        raise PluginError(f"message type {type_name} has views in several plugins: {owners}")
    fn = resolve(owners[0][1]) if owners else None
    _views[type_name] = fn
    return fn


@cache
def multi_view_types() -> frozenset[str]:
    """Every plugin's ``multi_views``: the message types whose map channel is ``foxglove.LocationFixes``."""
    return frozenset(t for p in plugins().values() for t in p.multi_views)


def report_sections() -> list[tuple[str, ReportSection]]:
    """(plugin name, its report section) of every plugin that has one, in page order (rank, then name)."""
    found = [(p.name, p.report) for p in plugins().values() if p.report is not None]
    return sorted(found, key=lambda nr: (nr[1].rank, nr[0]))
