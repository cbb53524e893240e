"""Terrain-aided navigation by recurrent search over a hypothesis grid with reliability conditions (digest 001).

Pure core: :class:`~services.terrain_nav.core.TerrainNavigator` (``step(message) -> [TerrainVerdict,
TerrainFix]``), the base algorithm of §2.13 for A/B comparison
(:class:`~services.terrain_nav.base_algorithm.BaseRecurrentSearch`), reference maps, synthetic terrain,
the flight simulation and Monte-Carlo metrics. No I/O beyond map loading, no Zenoh, no wall clock.
"""

from .base_algorithm import BaseRecurrentSearch
from .config import TerrainNavConfig
from .core import Evaluation, TerrainNavigator
from .maps import ReferenceMap, load_geotiff, load_npy, save_npy

__all__ = [
    "BaseRecurrentSearch",
    "Evaluation",
    "ReferenceMap",
    "TerrainNavConfig",
    "TerrainNavigator",
    "load_geotiff",
    "load_npy",
    "save_npy",
]
