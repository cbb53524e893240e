"""The pure part of the player: scenario + seed -> the ordered list of events it publishes (no Zenoh).

Randomness: the run's root seed sequence is ``SeedSequence(seed)`` for a single play and
``SeedSequence(seed).spawn(runs)[i]`` (= ``SeedSequence(seed, spawn_key=(i,))``) for Monte-Carlo run ``i``.
Each simulator draws from the child keyed by its ``id`` (see :func:`simulators.child_seed`), so the noise
of one simulator depends only on the seed, the run and its own id.

Order: all simulators' events merged by stamp; ties keep the order of the simulators in the file and,
within one simulator, the order it yielded them. Then ``header.source`` = ``player/<instance>`` and a
per-key ``header.seq`` counting from 0 are filled in.
"""

from __future__ import annotations

import heapq
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from schemas import Header, ScenarioMarker
from shared import keys

from .scenario import Scenario
from .simulators import (
    Event,
    Exchange,
    InteractiveSimulator,
    ScenarioContext,
    Simulator,
    child_seed,
    get_simulator,
)


class SimulationError(RuntimeError):
    """A simulator broke its contract (stamps out of order or out of range, header stamp mismatch)."""


def run_seed(seed: int, run: int | None = None) -> np.random.SeedSequence:
    """Root seed sequence of a single play (``run`` None) or of Monte-Carlo run ``run``."""
    if run is None:
        return np.random.SeedSequence(seed)
    return np.random.SeedSequence(seed, spawn_key=(run,))


def player_source(instance: str) -> str:
    return f"player/{keys.chunk(instance)}"


@dataclass
class Simulation:
    """The built simulators of one run and their shared context."""

    scenario: Scenario
    context: ScenarioContext
    simulators: list[tuple[str, Simulator]]

    def raw_events(self, exchanges: Mapping[str, Exchange] | None = None) -> Iterator[Event]:
        """Merged events as the simulators made them (source and seq not yet filled).

        ``exchanges`` (simulator id -> exchange) drives those interactive simulators through their
        ``interact(exchange)`` (the player's Zenoh exchange); every other simulator gives ``events()``, which for
        an interactive one is its in-process closed loop. The merge pulls lazily: an interactive simulator's next
        chunk is made only after the consumer took the last event of the previous one.
        """
        ex = exchanges or {}
        streams = [
            checked(sid, event_source(sim, ex.get(sid)), self.context.duration_ns) for sid, sim in self.simulators
        ]
        return heapq.merge(*streams, key=lambda e: e.stamp_ns)


def build(scenario: Scenario, seed: int, run: int | None = None) -> Simulation:
    """Build every simulator of ``scenario`` for one run, in file order."""
    root = run_seed(seed, run)
    context = ScenarioContext(
        scenario=scenario.name, frame_id=scenario.frame_id, duration_ns=scenario.duration_ns, seed=seed
    )
    built: list[tuple[str, Simulator]] = []
    for i, spec in enumerate(scenario.simulators):
        cls = get_simulator(spec.kind)
        rng = np.random.Generator(np.random.PCG64(child_seed(root, spec.id)))
        try:
            built.append((spec.id, cls(scenario.simulator_params(i), rng, context)))
        except (ValueError, KeyError, TypeError) as exc:  # e.g. a platform no earlier simulator flies
            raise SimulationError(f"simulator {spec.id!r} ({spec.kind}): {type(exc).__name__}: {exc}") from exc
    return Simulation(scenario, context, built)


def event_source(sim: Simulator, exchange: Exchange | None) -> Iterator[Event]:
    """``sim.interact(exchange)`` for an interactive simulator given an exchange, else ``sim.events()``."""
    if exchange is not None and isinstance(sim, InteractiveSimulator):
        return sim.interact(exchange)
    return sim.events()


def checked(sim_id: str, events: Iterable[Event], duration_ns: int) -> Iterator[Event]:
    """The events, raising :class:`SimulationError` at the first that breaks the simulator contract."""
    last = 0
    for ev in events:
        if ev.stamp_ns < last:
            raise SimulationError(f"simulator {sim_id!r}: stamp {ev.stamp_ns} ns after {last} ns on {ev.key}")
        if ev.stamp_ns > duration_ns:
            raise SimulationError(f"simulator {sim_id!r}: stamp {ev.stamp_ns} ns beyond the duration {duration_ns} ns")
        if ev.msg.header.stamp_ns != ev.stamp_ns:
            raise SimulationError(f"simulator {sim_id!r}: header stamp {ev.msg.header.stamp_ns} != event {ev.stamp_ns}")
        last = ev.stamp_ns
        yield ev


def stamp(events: Iterable[Event], source: str) -> Iterator[Event]:
    """Fill ``header.source`` and a per-key ``header.seq`` (0, 1, ...)."""
    seq: Counter[str] = Counter()
    for ev in events:
        header = ev.msg.header.model_copy(update={"source": source, "seq": seq[ev.key]})
        seq[ev.key] += 1
        yield Event(ev.stamp_ns, ev.key, ev.msg.model_copy(update={"header": header}))


def iter_events(
    scenario: Scenario, seed: int | None = None, *, run: int | None = None, instance: str = "default"
) -> Iterator[Event]:
    """Lazily, the events the player publishes between its start and end markers."""
    sim = build(scenario, scenario.seed if seed is None else seed, run)
    return stamp(sim.raw_events(), player_source(instance))


def scenario_events(
    scenario: Scenario, seed: int | None = None, *, run: int | None = None, instance: str = "default"
) -> list[Event]:
    """The ordered event list for a scenario and seed, exactly as ``fixstream play`` publishes it."""
    return list(iter_events(scenario, seed, run=run, instance=instance))


def marker(
    scenario: Scenario,
    seed: int,
    event: str,
    stamp_ns: int,
    seq: int,
    instance: str = "default",
    published: dict[str, int] | None = None,
) -> ScenarioMarker:
    """A start or end marker for ``fixstream/scenario/<name>``."""
    return ScenarioMarker(
        header=Header(stamp_ns=stamp_ns, frame_id=scenario.frame_id, source=player_source(instance), seq=seq),
        event="start" if event == "start" else "end",
        scenario=scenario.name,
        seed=seed,
        published=dict(published or {}),
    )
