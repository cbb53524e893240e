"""What the ``fixstream mc`` plugins' ``Params`` check alike: the ``config`` overrides of the estimator's core.

A plugin takes the core's configuration as overrides in ``params.config`` but sets the platform field itself
(from its own parameter); :func:`check_config_overrides` refuses that field in the overrides and reports the
first invalid override as ``config.<field>: <reason>``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from pydantic import ValidationError


def check_config_overrides(config: Mapping[str, Any], own: str, instead: str, build: Callable[[], object]) -> None:
    """Fails (ValueError) if ``config`` sets ``own`` (the message: ``config.<own>: give <instead>``) or if
    ``build()`` (the core's configuration with the overrides) does not validate."""
    if own in config:
        raise ValueError(f"config.{own}: give {instead}")
    try:
        build()
    except ValidationError as exc:
        first = exc.errors()[0]
        raise ValueError(f"config.{'.'.join(str(p) for p in first['loc'])}: {first['msg']}") from None
