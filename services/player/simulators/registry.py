"""The simulator registry: ``kind`` name -> simulator class.

A plugin module defines a class with a ``Params`` model and decorates it with ``@register("<kind>")``.
Modules are imported lazily, on the first lookup of their kind, from :data:`PLUGIN_MODULES`; an estimator
issue that brings a simulator adds one line there (``"<kind>": "services.<estimator>.simulator"``).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TypeVar

from .base import Simulator

#: kind -> module that registers it (imported on first use)
PLUGIN_MODULES: dict[str, str] = {
    "nav_platform": "services.player.simulators.nav_platform",
    # one per estimator issue; each module registers the kinds it simulates
    "lbl_nav": "services.lbl_nav.simulator",
    "terrain_nav": "services.terrain_nav.simulator",
    "rd_group": "services.rd_nav.simulator",
    "pcl_tracker": "services.pcl_tracker.simulator",
    "attitude": "services.attitude.simulator",
}

_REGISTRY: dict[str, type[Simulator]] = {}

S = TypeVar("S")


class UnknownSimulator(KeyError):
    """No simulator of that kind is registered or listed in :data:`PLUGIN_MODULES`."""

    def __str__(self) -> str:
        return str(self.args[0])


def register(kind: str) -> Callable[[S], S]:
    """Class decorator: make the simulator class available as ``kind`` in scenario files."""

    def wrap(cls: S) -> S:
        existing = _REGISTRY.get(kind)
        if existing is not None and existing is not cls:
            raise ValueError(f"simulator kind {kind!r} is registered twice ({existing!r} and {cls!r})")
        if not hasattr(cls, "Params"):
            raise TypeError(f"simulator {cls!r} has no Params model")
        _REGISTRY[kind] = cls  # type: ignore[assignment]
        return cls

    return wrap


def known_kinds() -> list[str]:
    return sorted(set(_REGISTRY) | set(PLUGIN_MODULES))


def get_simulator(kind: str) -> type[Simulator]:
    """The simulator class for ``kind`` (imports its plugin module if needed)."""
    cls = _REGISTRY.get(kind)
    if cls is None and kind in PLUGIN_MODULES:
        importlib.import_module(PLUGIN_MODULES[kind])
        cls = _REGISTRY.get(kind)
    if cls is None:
        raise UnknownSimulator(f"unknown simulator kind {kind!r}; known kinds: {', '.join(known_kinds())}")
    return cls
