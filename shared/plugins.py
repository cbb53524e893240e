"""The plugin contract: how a process folder (an estimator, the recorder, ...) makes itself known to the stack.

Each folder ``services/<name>/`` exports one :class:`Plugin` object in ``services/<name>/plugin.py`` and
registers it as a package entry point in the group ``fixstream.plugins``::

    [project.entry-points."fixstream.plugins"]
    lbl_nav = "services.lbl_nav.plugin:PLUGIN"

That line, the folder and its compose service are all that adding an estimator takes: ``fixstream run <name>``,
the player's simulator kinds, ``fixstream mc`` and the report find it through :func:`plugins` (ROS 2 packages
register their nodes the same way). Every part is named by a dotted ``module:attribute`` path and imported only
when used, so listing the plugins costs nothing and a service process imports only its own code.

The registry is runtime: it reads entry points and imports what they name, and never names a service itself.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from functools import cache
from importlib.metadata import entry_points
from typing import Any

from .errors import StartupError

GROUP = "fixstream.plugins"


class PluginError(StartupError):
    """No plugin of that name, or one whose parts do not resolve."""


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
