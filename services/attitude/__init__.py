"""Aircraft heading, pitch and roll from monostatic radar plots (digest 004): pure core, simulation, metrics.

The package imports nothing on purpose: loading the plugin registry (every ``services/*/plugin.py``) must
not import every estimator's core and its dependencies into every service process. Import the modules.
"""
