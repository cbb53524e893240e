"""The simulator registry: ``kind`` name -> simulator class.

A plugin module defines a class with a ``Params`` model and decorates it with ``@register("<kind>")``.
Modules are imported lazily, on the first lookup of their kind, from the ``simulators`` of the installed plugins
(:mod:`shared.plugins`): an estimator names its simulator kinds in its own ``plugin.py``, nothing here names it.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TypeVar

from shared.plugins import simulator_modules

from .base import Simulator


def plugin_modules() -> dict[str, str]:
    """kind -> module that registers it (imported on first use), from every installed plugin
    (:func:`shared.plugins.simulator_modules`)."""
    return simulator_modules()


_REGISTRY: dict[str, type[Simulator]] = {}

S = TypeVar("S")


class UnknownSimulator(KeyError):
    """No simulator of that kind is registered or named by a plugin."""

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
    return sorted(set(_REGISTRY) | set(plugin_modules()))


def get_simulator(kind: str) -> type[Simulator]:
    """The simulator class for ``kind`` (imports its plugin module if needed)."""
    cls = _REGISTRY.get(kind)
    modules = plugin_modules()
    if cls is None and kind in modules:
        importlib.import_module(modules[kind])
        cls = _REGISTRY.get(kind)
    if cls is None:
        raise UnknownSimulator(f"unknown simulator kind {kind!r}; known kinds: {', '.join(known_kinds())}")
    return cls
