"""Play a scenario onto Zenoh: wait for the named services, then start marker, events, end marker.

The events are exactly :func:`services.player.timeline.iter_events` (stamp order, ``header.source`` =
``player/<instance>``, per-key ``header.seq``), paced by their data stamps at ``rate`` times real time
(0: as fast as the network takes them). The end marker on ``fixstream/scenario/<name>`` carries the
number of messages published per key. The player holds the liveliness token
``fixstream/alive/player/<instance>`` while it runs.

An interactive simulator (a closed loop with a service, ``docs/scenarios.md``) gets a
:class:`~services.player.exchange.ZenohExchange`, subscribed to its reply key before the start marker: after
publishing a chunk of its events the player waits there for the service's answers to the chunk's requests before
the simulator makes the next chunk. Open-loop simulators are played exactly as before.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import zenoh

from shared import keys
from shared.recovery import Recovery
from shared.session import refuse_namesake
from shared.settings import ZenohSettings

from .exchange import ZenohExchange
from .pacing import Pacer
from .publish import Publishers
from .scenario import Scenario
from .simulators import InteractiveSimulator
from .timeline import build, marker, player_source
from .wire import wire_chunks

#: how long a player waits for another player of its instance to go before it refuses to start, s (a killed
#: player's token goes at once)
PLAYER_NAMESAKE_WAIT_S = 2.0

log = logging.getLogger("fixstream.player")


class WaitTimeout(TimeoutError):
    """The services a scenario waits for did not all become alive in time."""

    def __init__(self, missing: list[str], timeout_s: float) -> None:
        super().__init__(f"no live token on {', '.join(missing)} after {timeout_s:g} s")
        self.missing = missing


@dataclass
class PlayResult:
    """What one play published: counts per key (data only, markers excluded), and whether it completed."""

    published: dict[str, int]
    completed: bool
    wall_s: float
    #: per interactive simulator id: requests, answers, timeouts, missing (empty for open-loop scenarios)
    exchanges: dict[str, dict[str, int]] = field(default_factory=dict)

    @property
    def total(self) -> int:
        return sum(self.published.values())


def wait_for_alive(
    session: zenoh.Session, key_exprs: list[str], timeout_s: float, stop: threading.Event | None = None
) -> None:
    """Block until every key expression matches at least one liveliness token.

    Raises :class:`WaitTimeout` after ``timeout_s``; returns early, without raising, once ``stop`` is set.
    """
    if not key_exprs:
        return
    present: set[str] = set()
    lock = threading.Lock()
    changed = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        with lock:
            if sample.kind == zenoh.SampleKind.PUT:
                present.add(str(sample.key_expr))
            else:
                present.discard(str(sample.key_expr))
        changed.set()

    wanted = [zenoh.KeyExpr(k) for k in key_exprs]
    sub = session.liveliness().declare_subscriber(keys.ALIVE_ALL, on_sample, history=True)
    deadline = time.monotonic() + timeout_s
    try:
        while True:
            with lock:
                alive = [zenoh.KeyExpr(k) for k in present]
            missing = [str(w) for w in wanted if not any(w.intersects(a) for a in alive)]
            if not missing:
                log.info("alive: %s", ", ".join(key_exprs))
                return
            if stop is not None and stop.is_set():
                return  # interrupted: the caller checks ``stop``
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise WaitTimeout(missing, timeout_s)
            changed.wait(min(remaining, 0.5))
            changed.clear()
    finally:
        sub.undeclare()


def play_scenario(
    session: zenoh.Session,
    scenario: Scenario,
    *,
    seed: int | None = None,
    run: int | None = None,
    instance: str = "default",
    rate: float = 1.0,
    wait: bool = True,
    stop: threading.Event | None = None,
    progress: Callable[[int, int], None] | None = None,
    recovery: Recovery | None = None,
) -> PlayResult:
    """Publish one run of ``scenario``. ``stop`` ends it early (the end marker is still sent, with the counts).
    ``progress(messages published, data stamp ns)`` is called after every message. ``recovery``: the keys published
    with a cache for subscribers to recover from, and the replies subscribed with recovery (None: as
    :class:`ZenohSettings` of the environment says; shared/recovery.py)."""
    stop = stop or threading.Event()
    seed = scenario.seed if seed is None else seed
    scenario_key = keys.scenario(scenario.name)
    # one player per instance: two publish one source with two seq counters, and every consumer then counts most
    # of both streams lost (a churn audit: lost 254,348 of ~13,000 published) and refuses half as stamp_backwards
    refuse_namesake(session, keys.alive("player", instance), PLAYER_NAMESAKE_WAIT_S, stop)
    token = session.liveliness().declare_token(keys.alive("player", instance))
    recovery = recovery or Recovery.of(ZenohSettings())
    pubs = Publishers(session, recovery)
    exchanges: dict[str, ZenohExchange] = {}
    try:
        if wait:
            wait_for_alive(session, scenario.wait_keys(), scenario.wait_timeout_s, stop)
            if stop.is_set():
                log.warning("%s: stopped while waiting for %s", scenario.name, ", ".join(scenario.wait_for))
                return PlayResult({}, False, 0.0)
        pacer = Pacer(rate, stop)
        sim = build(scenario, seed, run)
        source = player_source(instance)
        for sid, s in sim.simulators:
            spec = s.exchange_spec() if isinstance(s, InteractiveSimulator) else None
            if spec is not None:
                exchanges[sid] = ZenohExchange(session, sid, spec, source, instance, stop, recovery)
        # the events of timeline.iter_events, encoded (wire.py: columns of nav_platform without a model per message)
        chunks = wire_chunks(sim, source, dict(exchanges))
        t0 = time.monotonic()
        last_stamp = 0
        pubs.put(scenario_key, marker(scenario, seed, "start", 0, 0, instance))
        completed = True
        paced = rate > 0
        stopped = stop.is_set
        put = pubs.put_bytes
        n_published = 0
        for stamps, keys_, encodings, payloads in chunks:
            for stamp_ns, key, encoding, payload in zip(stamps, keys_, encodings, payloads, strict=True):
                go_on = pacer.wait(stamp_ns) if paced else not stopped()
                if not go_on:
                    break
                put(key, payload, encoding)
                last_stamp = stamp_ns
                if progress is not None:
                    n_published += 1
                    progress(n_published, last_stamp)
            else:
                continue
            completed = False
            log.warning("stopped after %d messages", sum(pubs.counts.values()) - 1)
            break
        published = {k: n for k, n in pubs.counts.items() if k != scenario_key}
        pubs.put(scenario_key, marker(scenario, seed, "end", last_stamp, 1, instance, published))
        wall = time.monotonic() - t0
        log.info(
            "%s: published %d messages on %d keys in %.2f s",
            scenario.name,
            sum(published.values()),
            len(published),
            wall,
        )
        for sid, ex in exchanges.items():
            log.info("%s: exchanges of %s: %s", scenario.name, sid, dict(ex.stats))
        return PlayResult(published, completed, wall, {sid: dict(ex.stats) for sid, ex in exchanges.items()})
    finally:
        for ex in exchanges.values():
            ex.close()
        pubs.close()
        with contextlib.suppress(Exception):
            token.undeclare()
