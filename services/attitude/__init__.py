"""Aircraft heading, pitch and roll from monostatic radar plots (digest 004): pure core, simulation, metrics."""

from .config import RADAR_PRESETS, AttitudeConfig, MeasurementSigmas
from .core import AttitudeCore, TrackSnapshot

__all__ = ["RADAR_PRESETS", "AttitudeConfig", "AttitudeCore", "MeasurementSigmas", "TrackSnapshot"]
