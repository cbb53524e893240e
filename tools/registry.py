"""Find services by name: ``services/<name>/service.py`` exposes ``build() -> Service``."""

from __future__ import annotations

import importlib

from shared.errors import StartupError
from shared.service import Service


def load_service(name: str) -> Service:
    try:
        module = importlib.import_module(f"services.{name}.service")
    except ModuleNotFoundError as exc:
        if exc.name and exc.name.startswith(f"services.{name}"):
            raise StartupError(f"no service named {name!r} (looked for services/{name}/service.py)") from None
        raise
    service: Service = module.build()
    return service
