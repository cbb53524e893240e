"""Find services by name through the plugin registry: ``fixstream run <name>`` builds ``plugin(name).service``."""

from __future__ import annotations

from shared.errors import StartupError
from shared.plugins import PluginError, plugin, resolve
from shared.service import Service


def load_service(name: str) -> Service:
    try:
        found = plugin(name)
    except PluginError as exc:
        raise StartupError(str(exc)) from None
    if found.service is None:
        raise StartupError(f"{name!r} is not a service one runs with fixstream run ({found.summary})")
    service: Service = resolve(found.service)()
    return service
