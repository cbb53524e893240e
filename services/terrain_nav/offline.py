"""Runs a navigator (modified or base) over a simulated flight through its ``step()`` interface.

The same core the service will call: each input message goes through ``step``; refused inputs
(:class:`InputRejected`) are counted by reason, exactly as the service adapter will report them.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Literal

from schemas import Message
from schemas.terrain_nav import TerrainFix, TerrainVerdict
from shared.errors import InputRejected

from .base_algorithm import BaseRecurrentSearch
from .config import TerrainNavConfig
from .core import TerrainNavigator
from .simulation import SimulatedFlight

Algorithm = Literal["modified", "base"]


@dataclass
class RunResult:
    """Outputs of one run: every message, the verdicts and fixes, and the refused inputs by reason."""

    flight: SimulatedFlight
    algorithm: Algorithm
    navigator: TerrainNavigator
    outputs: list[Message] = field(default_factory=list)
    rejected: Counter[str] = field(default_factory=Counter)
    cpu_s: float = 0.0

    @property
    def verdicts(self) -> list[TerrainVerdict]:
        return [m for m in self.outputs if isinstance(m, TerrainVerdict)]

    @property
    def fixes(self) -> list[TerrainFix]:
        return [m for m in self.outputs if isinstance(m, TerrainFix)]


def make_navigator(flight: SimulatedFlight, cfg: TerrainNavConfig, algorithm: Algorithm) -> TerrainNavigator:
    ref = flight.world.ref_map
    return BaseRecurrentSearch(ref, cfg) if algorithm == "base" else TerrainNavigator(ref, cfg)


def run_flight(
    flight: SimulatedFlight,
    cfg: TerrainNavConfig | None = None,
    algorithm: Algorithm = "modified",
    stop_at_first_fix: bool = False,
) -> RunResult:
    """Feed every message of the flight to a fresh navigator; collect its outputs."""
    cfg = cfg or TerrainNavConfig()
    nav = make_navigator(flight, cfg, algorithm)
    res = RunResult(flight=flight, algorithm=algorithm, navigator=nav)
    t0 = time.process_time()
    for msg in flight.messages():
        try:
            out = nav.step(msg)
        except InputRejected as exc:
            res.rejected[exc.reason] += 1
            continue
        if out:
            res.outputs.extend(out)
            if stop_at_first_fix and any(isinstance(m, TerrainFix) for m in out):
                break
    res.cpu_s = time.process_time() - t0
    return res
