"""YAML as a scenario author writes it: ``1e6`` is a number.

PyYAML follows YAML 1.1, where a float needs a dot: ``duration_s: 1e9`` was read as the string ``'1e9'`` and refused
with "Input should be a valid number (got '1e9')" (a new user's audit). YAML 1.2, and every other reader a user
meets (JSON, Python, numpy), reads it as 10^9. :func:`load` is ``yaml.safe_load`` with the YAML 1.2 float form
added; every other value reads as before.
"""

from __future__ import annotations

import re
from typing import Any

import yaml


class _Loader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that also reads an exponent without a dot (``1e6``, ``-2.5E-3`` as before) as a float."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def load(text: str | bytes) -> Any:
    """``yaml.safe_load(text)``, where ``1e6`` is the float 1000000.0 (YAML 1.2)."""
    return yaml.load(text, Loader=_Loader)


__all__ = ["load"]
