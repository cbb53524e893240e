"""PCL tracker (digest 003): bistatic association, Cartesian UKF, 2/L initiation, M/N confirmation.

The pure core is :class:`services.pcl_tracker.core.PclTracker`; see ``docs/pcl_tracker.md``.

The package imports nothing on purpose: loading the plugin registry (every ``services/*/plugin.py``) must
not import every estimator's core and its dependencies into every service process. Import the modules.
"""
