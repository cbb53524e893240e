"""What every simulator plugin builds on: the event tuple, the scenario context and the plugin protocol.

A simulator is built once per run from its validated parameters, its own ``numpy.random.Generator`` and
the :class:`ScenarioContext`, and then yields :class:`Event` tuples ``(stamp_ns, key, msg)`` in
non-decreasing ``stamp_ns`` order, all within ``[0, context.duration_ns]``. Stamps are on the simulated
clock (ns since scenario start). The player fills ``header.source`` and ``header.seq``; a simulator sets
``header.stamp_ns`` (equal to the event stamp) and ``header.frame_id`` (``context.frame_id``).

**Interactive simulators** (closed loop, ``docs/scenarios.md``): a simulator that must react to a service's
answers (a group of AUVs obeying the base coordinator's beacon assignments) also implements
:class:`InteractiveSimulator`. Its :meth:`~InteractiveSimulator.interact` generator yields events chunk by chunk
and, after the last event of a chunk that holds *requests* (events a service answers), calls ``exchange(requests)``
and feeds the answers back before it makes the next chunk. The player passes an exchange that waits for the
answers on Zenoh (:mod:`services.player.exchange`); ``events()`` passes the simulator's own in-process one
(``fixstream mc``, ``scenario_events``). Same generator, two drivers: the event stream is identical when the
service answers as the in-process twin does.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, runtime_checkable

import numpy as np
from pydantic import BaseModel, ConfigDict

from schemas import Header, Message
from shared.events import Event

if TYPE_CHECKING:
    from .columns import ColumnStream

NS_PER_S = 1_000_000_000


class SimParams(BaseModel):
    """Base of every simulator's parameter model: strict, closed and frozen (errors name the field)."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True, allow_inf_nan=False)


@dataclass(frozen=True)
class TruthState:
    """True kinematic state of a platform at n instants, in the scenario frame (east, north, up)."""

    position_m: np.ndarray  #: (n, 3) [east, north, up], m
    velocity_mps: np.ndarray  #: (n, 3) [east, north, up], m/s
    heading_rad: np.ndarray  #: (n,) clockwise from north, in [0, 2*pi)
    pitch_rad: np.ndarray  #: (n,) nose up positive
    roll_rad: np.ndarray  #: (n,) starboard down positive


@runtime_checkable
class TruthSource(Protocol):
    """Anything that can tell a platform's exact true state at given stamps (a trajectory, for example)."""

    def truth_at(self, stamps_ns: np.ndarray) -> TruthState: ...


#: periodic samples (sensor and truth streams) one run of a scenario may hold: about 2 KiB of events each in memory,
#: so a few GiB at most (the largest shipped scenario holds far fewer: tests/test_scenarios_budget.py)
MAX_SCENARIO_SAMPLES = 2_000_000


@dataclass
class ScenarioContext:
    """What a simulator knows about the scenario besides its own parameters.

    ``platforms`` maps a platform id to the source of its exact truth. Simulators are built in the order
    they appear in the scenario file; one that flies a platform registers it here, so a simulator listed
    after it (beacon ranges, radar plots of that platform) can look the trajectory up.
    """

    scenario: str
    frame_id: str
    duration_ns: int
    seed: int
    platforms: dict[str, TruthSource] = field(default_factory=dict)
    #: periodic samples the simulators built so far have asked for (:meth:`reserve_samples`)
    samples_reserved: int = 0

    @property
    def duration_s(self) -> float:
        return self.duration_ns / NS_PER_S

    def header(self, stamp_ns: int) -> Header:
        """A header stamped on the simulated clock in the scenario frame (source and seq set by the player)."""
        return Header(stamp_ns=stamp_ns, frame_id=self.frame_id)

    def reserve_samples(self, n: int, what: str) -> None:
        """Count ``n`` periodic samples of ``what`` against :data:`MAX_SCENARIO_SAMPLES`, before they are built:
        ``ValueError`` (a one-line error of the scenario) when the run would exceed it. A scenario that asked for
        1,000 Hz for 10^6 s passed validation and then took the machine's 24 GiB building its events."""
        self.samples_reserved += n
        if self.samples_reserved > MAX_SCENARIO_SAMPLES:
            raise ValueError(
                f"{what}: {n:,} samples make {self.samples_reserved:,} in this scenario, more than the "
                f"{MAX_SCENARIO_SAMPLES:,} a run may hold in memory; shorten duration_s or lower the rate"
            )

    def register_platform(self, platform: str, source: TruthSource) -> None:
        if platform in self.platforms:
            raise ValueError(f"platform {platform!r} is flown by two simulators")
        self.platforms[platform] = source


class Simulator(Protocol):
    """The plugin protocol. ``Params`` is the plugin's own parameter model (a :class:`SimParams`)."""

    Params: ClassVar[type[SimParams]]

    def __init__(self, params: Any, rng: np.random.Generator, context: ScenarioContext) -> None: ...

    def events(self) -> Iterator[Event]:
        """Events in non-decreasing stamp order, each within ``[0, context.duration_ns]``."""
        ...


#: the player side of a closed loop: given the requests of a chunk (events already published, in order), the
#: answers to them (the reply messages, in request order; a request whose answer did not come in time has none)
Exchange = Callable[[list[Event]], list[Message]]


@dataclass(frozen=True)
class ExchangeSpec:
    """Where an interactive simulator's answers come from and how to tell which request one answers."""

    #: key expression the answering service publishes its replies on
    reply_key: str
    #: (request header.source, request key, request header.seq) that a reply answers, or None if not a reply
    answers: Callable[[Message], tuple[str, str, int] | None]
    #: wall time to wait for the answers to one chunk's requests, s (then the run proceeds without them)
    timeout_s: float = 10.0


@runtime_checkable
class InteractiveSimulator(Protocol):
    """A simulator in a closed loop with a service (see the module docstring). ``events()`` must equal
    ``interact(<its in-process exchange>)``."""

    Params: ClassVar[type[SimParams]]

    def events(self) -> Iterator[Event]: ...

    def exchange_spec(self) -> ExchangeSpec | None:
        """How the answers come (None: this run asks nothing, e.g. an open-loop configuration)."""
        ...

    def interact(self, exchange: Exchange) -> Iterator[Event]:
        """Events as ``events()``, asking ``exchange`` for the answers to each chunk's requests."""
        ...


@runtime_checkable
class ColumnarSimulator(Protocol):
    """A simulator whose streams are columns (:mod:`.columns`), so the player can encode them without building a
    model per message. ``events()`` must be the stamp-ordered merge of the streams' events, ties in list order."""

    Params: ClassVar[type[SimParams]]

    def events(self) -> Iterator[Event]: ...

    def column_streams(self) -> list[ColumnStream]: ...


def is_interactive(sim: object) -> bool:
    """True if ``sim`` implements :class:`InteractiveSimulator` and this run exchanges with a service."""
    return isinstance(sim, InteractiveSimulator) and sim.exchange_spec() is not None


def stable_id(name: str) -> int:
    """A 64-bit integer derived from ``name`` only (same on every machine and Python run)."""
    return int.from_bytes(hashlib.blake2b(name.encode(), digest_size=8).digest(), "little")


def child_seed(parent: np.random.SeedSequence, name: str) -> np.random.SeedSequence:
    """The seed sequence of the stream called ``name`` under ``parent``.

    Keyed by name, not by position: adding a simulator or a sensor does not change the noise of the others.
    """
    return np.random.SeedSequence(entropy=parent.entropy, spawn_key=(*parent.spawn_key, stable_id(name)))


def child_rng(rng: np.random.Generator, name: str) -> np.random.Generator:
    """An independent generator for the sub-stream ``name`` of ``rng`` (e.g. one per sensor)."""
    seq = rng.bit_generator.seed_seq
    if not isinstance(seq, np.random.SeedSequence):
        raise TypeError("child_rng needs a Generator built from a numpy SeedSequence")
    return np.random.Generator(np.random.PCG64(child_seed(seq, name)))


def sample_stamps_ns(
    rate_hz: float, duration_ns: int, start_s: float = 0.0, *, budget: tuple[ScenarioContext, str] | None = None
) -> np.ndarray:
    """Stamps of a periodic stream: ``start + k / rate`` for every k with the stamp within the duration (ns).
    ``budget``: the scenario's context and the stream's name, to count the samples against what a run may hold
    (:meth:`ScenarioContext.reserve_samples`) before they are allocated."""
    period_ns = max(1, round(NS_PER_S / rate_hz))
    start_ns = round(start_s * NS_PER_S)
    if start_ns > duration_ns:
        return np.zeros(0, dtype=np.int64)
    n = (duration_ns - start_ns) // period_ns + 1
    if budget is not None:
        budget[0].reserve_samples(n, budget[1])
    return start_ns + period_ns * np.arange(n, dtype=np.int64)
