"""The typed contract of every fixstream stream (pydantic v2 models) and its JSON Schema export."""

from .acoustic import AcousticArrival, Beacon, BeaconRange, BeaconTable, NavPacket
from .base import MODELS, Covariance, Header, Message, StrictModel, Vec2, Vec3
from .diagnostics import Diagnostic
from .estimate import GaussianEstimate, Layout
from .navigation import (
    Attitude,
    BaroAltitude,
    Current,
    Depth,
    Heading,
    InsSample,
    NavReset,
    RadioAltimeter,
    SoundSpeed,
    SpeedLog,
)
from .outputs import Fix, Hypothesis, Track
from .radar import BistaticConfigUpdate, BistaticPlot, BistaticScan, RadarPlot, RadarSite, TrackEnd
from .truth import ScenarioMarker, Truth


def _import_all_schema_modules() -> None:
    """Import every module of this package so each model registers in MODELS (estimators add files)."""
    import importlib
    import pkgutil

    for info in pkgutil.iter_modules(__path__):
        if info.name not in {"export"}:
            importlib.import_module(f"{__name__}.{info.name}")


_import_all_schema_modules()

__all__ = [
    "MODELS",
    "AcousticArrival",
    "Attitude",
    "BaroAltitude",
    "Beacon",
    "BeaconRange",
    "BeaconTable",
    "BistaticConfigUpdate",
    "BistaticPlot",
    "BistaticScan",
    "Covariance",
    "Current",
    "Depth",
    "Diagnostic",
    "Fix",
    "GaussianEstimate",
    "Header",
    "Heading",
    "Hypothesis",
    "InsSample",
    "Layout",
    "Message",
    "NavPacket",
    "NavReset",
    "RadarPlot",
    "RadarSite",
    "RadioAltimeter",
    "ScenarioMarker",
    "SoundSpeed",
    "SpeedLog",
    "StrictModel",
    "Track",
    "TrackEnd",
    "Truth",
    "Vec2",
    "Vec3",
]
