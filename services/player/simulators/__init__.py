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
from .registry import PLUGIN_MODULES, UnknownSimulator, get_simulator, known_kinds, register

__all__ = [
    "NS_PER_S",
    "PLUGIN_MODULES",
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
    "register",
    "sample_stamps_ns",
]
