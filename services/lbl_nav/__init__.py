"""LBL navigation of an AUV with no prior position and sparse beacons (digest 000, Koshaev & Bogomolov 2024).

Pure core: :class:`services.lbl_nav.core.LblNavCore` (``step(message) -> outputs``), configured by
:class:`services.lbl_nav.config.LblNavConfig`. See ``docs/lbl_nav.md``.

The package imports nothing on purpose: loading the plugin registry (every ``services/*/plugin.py``) must
not import every estimator's core and its dependencies into every service process. Import the modules.
"""
