"""Terrain-aided navigation by recurrent search over a hypothesis grid with reliability conditions (digest 001).

Pure core: :class:`~services.terrain_nav.core.TerrainNavigator` (``step(message) -> [TerrainVerdict,
TerrainFix]``), the base algorithm of §2.13 for A/B comparison
(:class:`~services.terrain_nav.base_algorithm.BaseRecurrentSearch`), reference maps, synthetic terrain,
the flight simulation and Monte-Carlo metrics. No I/O beyond map loading, no Zenoh, no wall clock.

The package imports nothing on purpose: loading the plugin registry (every ``services/*/plugin.py``) must
not import every estimator's core and its dependencies into every service process. Import the modules.
"""
