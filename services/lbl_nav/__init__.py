"""LBL navigation of an AUV with no prior position and sparse beacons (digest 000, Koshaev & Bogomolov 2024).

Pure core: :class:`services.lbl_nav.core.LblNavCore` (``step(message) -> outputs``), configured by
:class:`services.lbl_nav.config.LblNavConfig`. See ``docs/lbl_nav.md``.
"""

from .config import LblNavConfig
from .core import LblNavCore

__all__ = ["LblNavConfig", "LblNavCore"]
