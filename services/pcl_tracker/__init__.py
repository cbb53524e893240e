"""PCL tracker (digest 003): bistatic association, Cartesian UKF, 2/L initiation, M/N confirmation.

The pure core is :class:`services.pcl_tracker.core.PclTracker`; see ``docs/pcl_tracker.md``.
"""

from .config import PclTrackerConfig
from .core import PclTracker

__all__ = ["PclTracker", "PclTrackerConfig"]
