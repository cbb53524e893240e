"""The Service base ends a scenario run once every message the player's end marker announced has arrived.

Zenoh delivers each subscription on its own thread, so the end marker (``fixstream/scenario/<name>``) can
overtake the last data. These tests feed the reorderings that can happen and check the estimator's
``on_scenario_end`` runs exactly once, after the last announced message, whatever that message's fate.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable

import zenoh
from conftest import wait_until

from schemas import Depth, Header, Message, ScenarioMarker
from shared import codec, keys
from shared.service import InputRejected, Output, Service, Subscription
from shared.session import open_session
from shared.settings import ServiceSettings, ZenohSettings

KEY_A = "fixstream/sensor/auv1/depth/a"
KEY_B = "fixstream/sensor/auv1/depth/b"
OUT = "fixstream/fix/sum/auv1"
SCEN = keys.scenario("s")


class RunSum(Service):
    """Sums the depths of a run; publishes the sum (as a Depth) at the end of the run. Refuses depths > 100 m."""

    name = "runsum_test"

    def __init__(self, settings: ServiceSettings, zenoh_settings: ZenohSettings | None = None) -> None:
        super().__init__(settings, zenoh_settings)
        self.total = 0.0
        self.ends: list[tuple[str, float]] = []
        self.starts = 0

    def subscriptions(self) -> list[Subscription]:
        return [Subscription("fixstream/sensor/auv1/depth/*", self.on_depth, accepts=(Depth,))]

    def on_depth(self, key: str, msg: Message) -> list[Output]:
        assert isinstance(msg, Depth)
        if msg.depth_m > 100.0:
            raise InputRejected("too_deep", f"{msg.depth_m} m")
        self.total += msg.depth_m
        return []

    def on_scenario_start(self, marker: ScenarioMarker) -> Iterable[Output]:
        self.starts += 1
        return ()

    def on_scenario_end(self, marker: ScenarioMarker) -> list[Output]:
        self.ends.append((marker.scenario, self.total))
        out = [Output(OUT, Depth(header=Header(stamp_ns=marker.header.stamp_ns), depth_m=self.total))]
        self.total = 0.0
        return out


PLAYER = "player/test"


def depth(t: int, d: float) -> Depth:
    return Depth(header=Header(stamp_ns=t), depth_m=d)


def end(published: dict[str, int], name: str = "s") -> ScenarioMarker:
    header = Header(stamp_ns=10, source=PLAYER, seq=1)
    return ScenarioMarker(header=header, event="end", scenario=name, seed=0, published=published)


START = ScenarioMarker(header=Header(stamp_ns=0, source="player/test"), event="start", scenario="s", seed=0)


def feed(svc: Service, events: list[tuple[str, Message]], source: str = PLAYER) -> None:
    """``process`` each event as a session would (no final end of input, unlike ``run_offline``), stamped as the
    player stamps them: its source, and per key a seq counting from 0 (from 0 again after a start marker)."""
    svc._subs = svc.subscriptions()
    seq: dict[str, int] = getattr(svc, "_test_seq", {})
    svc._test_seq = seq  # type: ignore[attr-defined]
    for key, msg in events:
        if isinstance(msg, ScenarioMarker) and msg.event == "start":
            seq.clear()
        n = seq.get(key, 0)
        seq[key] = n + 1
        svc.process(key, codec.encode_stamped(msg, source, n), codec.encoding_of(type(msg)))


def sums(svc: Service) -> list[float]:
    return [o.msg.depth_m for o in svc.outbox if o.key == OUT]  # type: ignore[attr-defined]


def test_end_marker_overtaking_the_data_waits_for_every_announced_message() -> None:
    svc = RunSum(ServiceSettings(instance="t"))
    # the marker announces 3 on A, 2 on B and a key the service does not subscribe to (ignored)
    marker = end({KEY_A: 3, KEY_B: 2, "fixstream/truth/auv1": 7})
    feed(svc, [(KEY_A, depth(1, 1.0)), (KEY_B, depth(1, 10.0)), (SCEN, marker), (KEY_A, depth(2, 2.0))])
    assert svc.ends == [] and svc.status()["scenario"]["end_pending"]
    feed(svc, [(KEY_B, depth(2, 20.0))])
    assert svc.ends == []  # A still owes one message
    feed(svc, [(KEY_A, depth(3, 3.0))])
    assert svc.ends == [("s", 36.0)] and sums(svc) == [36.0]
    assert svc.status()["scenario"] == {"end_pending": False, "ends": {"complete": 1}, "stray_resets": 0}


def test_a_rejected_last_message_still_completes_the_run() -> None:
    svc = RunSum(ServiceSettings(instance="t"))
    feed(svc, [(KEY_A, depth(1, 5.0)), (SCEN, end({KEY_A: 2})), (KEY_A, depth(2, 500.0))])
    assert svc.ends == [("s", 5.0)] and svc.counters.rejected_by_reason == {"too_deep": 1}
    c = svc.counters
    assert c.received == c.accepted + c.rejected == 3


def test_early_samples_of_the_next_run_keep_their_count() -> None:
    """Run 2's first message arrives before run 1's end completes: it must count towards run 2, not run 1."""
    svc = RunSum(ServiceSettings(instance="t"))
    events: list[tuple[str, Message]] = [
        (KEY_A, depth(1, 1.0)),
        (SCEN, end({KEY_A: 2})),
        (KEY_A, depth(2, 2.0)),  # completes run 1 (2 of 2)
        (KEY_A, depth(1, 4.0)),  # run 2, whose end marker comes later
        (SCEN, end({KEY_A: 1}, "s2")),
    ]
    feed(svc, events)
    assert svc.ends == [("s", 3.0), ("s2", 4.0)]


def test_a_lost_message_ends_the_run_at_the_next_start_or_after_end_wait() -> None:
    svc = RunSum(ServiceSettings(instance="t"))
    feed(svc, [(KEY_A, depth(1, 1.0)), (SCEN, end({KEY_A: 2})), (SCEN, START), (KEY_A, depth(1, 7.0))])
    assert svc.ends == [("s", 1.0)] and svc.starts == 1 and svc.total == 7.0
    assert svc.status()["scenario"]["ends"] == {"incomplete": 1}
    # no next start: end_wait_s of quiet ends it (0 s here, so the next housekeeping tick does)
    svc = RunSum(ServiceSettings(instance="t", end_wait_s=0.0))
    feed(svc, [(KEY_A, depth(1, 1.0)), (SCEN, end({KEY_A: 2}))])
    assert svc.ends == []
    svc._idle()
    assert svc.ends == [("s", 1.0)] and sums(svc) == [1.0]


def test_run_offline_ends_a_pending_run_after_its_last_event() -> None:
    svc = RunSum(ServiceSettings(instance="t"))
    out = svc.run_offline([(KEY_A, depth(1, 1.0)), (SCEN, end({KEY_A: 2}))])
    assert [o.msg.depth_m for o in out if o.key == OUT] == [1.0]  # type: ignore[attr-defined]
    assert svc.status()["scenario"]["ends"] == {"incomplete": 1}


def test_over_a_router_the_run_ends_after_the_data(router: str) -> None:
    """Markers and data published on different keys by one publisher session: the sum covers every message."""
    zs = ZenohSettings(mode="client", connect=[router])
    svc = RunSum(ServiceSettings(instance="t1"), zs)
    thread = threading.Thread(target=svc.run, daemon=True)
    thread.start()
    client = open_session(zs)
    try:
        alive = keys.alive("runsum_test", "t1")
        assert wait_until(lambda: len(list(client.liveliness().get(alive, timeout=0.5))) == 1)
        got: list[float] = []
        sub = client.declare_subscriber(
            OUT, lambda s: got.append(codec.decode(s.payload.to_bytes(), str(s.encoding)).depth_m)
        )  # type: ignore[attr-defined]
        enc = zenoh.Encoding(codec.encoding_of(Depth))
        n = 500
        for i in range(n):
            payload = codec.encode_stamped(depth(i, 1.0), PLAYER, i // 2)  # as the player stamps: seq per key
            client.put(KEY_A if i % 2 else KEY_B, payload, encoding=enc)
        m = end({KEY_A: n // 2, KEY_B: n // 2})
        client.put(SCEN, codec.encode(m), encoding=zenoh.Encoding(codec.encoding_of(ScenarioMarker)))
        assert wait_until(lambda: got == [float(n)], timeout=20)
        sub.undeclare()
    finally:
        svc.stop()
        thread.join(timeout=10)
        client.close()
    assert svc.status()["scenario"]["ends"] == {"complete": 1}
