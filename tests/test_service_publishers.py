"""The Service base keeps a bounded set of declared publishers (one per output key, least recently used out)."""

from __future__ import annotations

import threading
from typing import ClassVar

import zenoh
from conftest import wait_until

from schemas import Depth, Header, Message, SoundSpeed
from shared import codec, keys
from shared.service import Output, Service, Subscription
from shared.session import open_session
from shared.settings import ServiceSettings, ZenohSettings

IN_KEY = "fixstream/sensor/auv1/depth/d0"


class Fanout(Service):
    """Republishes each depth on ``fixstream/fix/fan/auv1/k<depth mod 5>``; keeps at most 2 publishers."""

    name = "fanout_test"
    max_publishers: ClassVar[int] = 2

    def subscriptions(self) -> list[Subscription]:
        return [Subscription(IN_KEY, self.on_depth, accepts=(Depth,))]

    def on_depth(self, key: str, msg: Message) -> list[Output]:
        assert isinstance(msg, Depth)
        return [Output(keys.fix("fan", "auv1", f"k{int(msg.depth_m) % 5}"), msg)]


def test_publishers_beyond_the_bound_are_recycled_without_losing_messages_or_seq(router: str) -> None:
    zs = ZenohSettings(mode="client", connect=[router])
    svc = Fanout(ServiceSettings(instance="t1"), zs)
    thread = threading.Thread(target=svc.run, daemon=True)
    thread.start()
    client = open_session(zs)
    got: list[tuple[str, Message]] = []
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        msg = codec.decode(sample.payload.to_bytes(), str(sample.encoding))
        with lock:
            got.append((str(sample.key_expr), msg))

    try:
        assert wait_until(lambda: len(list(client.liveliness().get(keys.alive("fanout_test", "t1"), timeout=0.5))) == 1)
        sub = client.declare_subscriber("fixstream/fix/fan/auv1/*", on_sample)
        enc = zenoh.Encoding(codec.encoding_of(Depth))
        n = 200
        for i in range(n):
            client.put(IN_KEY, codec.encode(Depth(header=Header(stamp_ns=i), depth_m=float(i))), encoding=enc)
        assert wait_until(lambda: len(got) == n, timeout=20), len(got)
        assert len(svc._publishers) == 2  # bounded, while 5 keys were used
        sub.undeclare()
    finally:
        svc.stop()
        thread.join(timeout=10)
        client.close()
    per_key: dict[str, list[Message]] = {}
    for k, m in got:
        per_key.setdefault(k, []).append(m)
    assert sorted(per_key) == [f"fixstream/fix/fan/auv1/k{j}" for j in range(5)]
    for k, msgs in per_key.items():
        j = int(k[-1])
        assert [m.depth_m for m in msgs] == [float(i) for i in range(n) if i % 5 == j]  # type: ignore[attr-defined]
        assert [m.header.seq for m in msgs] == list(range(len(msgs)))  # seq per key survives the recycling


class Mixed(Service):
    """Takes depths on a wildcard (declares at most 2 of the keys it receives on) and answers each on one key with a
    Depth (even depth) or a SoundSpeed (odd): two types through the one publisher of that key."""

    name = "mixed_test"
    max_wire_keys: ClassVar[int] = 2

    def subscriptions(self) -> list[Subscription]:
        return [Subscription("fixstream/sensor/auv1/depth/*", self.on_depth, accepts=(Depth,))]

    def on_depth(self, key: str, msg: Message) -> list[Output]:
        assert isinstance(msg, Depth)
        i = int(msg.depth_m)
        out: Message = msg if i % 2 == 0 else SoundSpeed(header=msg.header, c_mps=1400.0 + i)
        return [Output(keys.fix("mix", "auv1", "out"), out)]


def test_one_key_carries_two_types_with_their_encodings_and_wildcard_keys_are_declared_up_to_the_bound(
    router: str,
) -> None:
    zs = ZenohSettings(mode="client", connect=[router])
    svc = Mixed(ServiceSettings(instance="t1"), zs)
    thread = threading.Thread(target=svc.run, daemon=True)
    thread.start()
    client = open_session(zs)
    got: list[tuple[str, Message]] = []
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        encoding = str(sample.encoding)
        msg = codec.decode(sample.payload.to_bytes(), encoding)  # a wrong encoding fails validation here
        with lock:
            got.append((encoding, msg))

    n = 30
    try:
        assert wait_until(lambda: len(list(client.liveliness().get(keys.alive("mixed_test", "t1"), timeout=0.5))) == 1)
        sub = client.declare_subscriber(keys.fix("mix", "auv1", "out"), on_sample)
        enc = zenoh.Encoding(codec.encoding_of(Depth))
        pubs = [client.declare_publisher(f"fixstream/sensor/auv1/depth/d{j}") for j in range(3)]
        for i in range(n):  # d0, d1, d2, d0, ...: three keys on the one wildcard
            pubs[i % 3].put(codec.encode(Depth(header=Header(stamp_ns=i), depth_m=float(i))), encoding=enc)
            wait_until(lambda i=i: len(got) > i, timeout=10)  # one at a time: the outputs' order is the inputs'
        assert wait_until(lambda: len(got) == n, timeout=20), len(got)
        sub.undeclare()
    finally:
        svc.stop()
        thread.join(timeout=10)
        client.close()
    assert svc.counters.received == n and svc.counters.rejected == 0  # keys beyond the bound arrive all the same
    assert sorted(svc._wire_keys) == ["fixstream/sensor/auv1/depth/d0", "fixstream/sensor/auv1/depth/d1"]
    assert [e for e, _ in got] == [codec.encoding_of(Depth if i % 2 == 0 else SoundSpeed) for i in range(n)]
    assert [type(m) for _, m in got] == [Depth if i % 2 == 0 else SoundSpeed for i in range(n)]
    assert [m.header.seq for _, m in got] == list(range(n))  # one seq per key, whatever the type
