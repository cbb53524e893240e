"""Pluggable scenario simulators: the registry, the plugin protocol and the built-in ``nav_platform``."""

from .base import (
    NS_PER_S,
    ColumnarSimulator,
    Event,
    Exchange,
    ExchangeSpec,
    InteractiveSimulator,
    ScenarioContext,
    SimParams,
    Simulator,
    TruthSource,
    TruthState,
    child_rng,
    child_seed,
    is_interactive,
    sample_stamps_ns,
)
from .registry import UnknownSimulator, get_simulator, known_kinds, plugin_modules, register

__all__ = [
    "NS_PER_S",
    "ColumnarSimulator",
    "Event",
    "Exchange",
    "ExchangeSpec",
    "InteractiveSimulator",
    "ScenarioContext",
    "SimParams",
    "Simulator",
    "TruthSource",
    "TruthState",
    "UnknownSimulator",
    "child_rng",
    "child_seed",
    "get_simulator",
    "is_interactive",
    "known_kinds",
    "plugin_modules",
    "register",
    "sample_stamps_ns",
]
