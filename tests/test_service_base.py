"""The Service base over a real router: dispatch, rejection reporting, status, liveliness, shutdown."""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Iterator

import msgpack
import pytest
import zenoh
from conftest import wait_until

from schemas import Depth, Diagnostic, Header, Heading, Message
from shared import codec, keys
from shared.service import InputRejected, Output, Service, Subscription
from shared.session import open_session
from shared.settings import ServiceSettings, ZenohSettings

IN_KEY = "fixstream/sensor/auv1/depth/d0"
OUT_KEY = "fixstream/fix/echo/auv1"
ENC = codec.encoding_of(Depth)


class DepthEcho(Service):
    """Republishes depths, refuses depths over 100 m and fails (a bug) at exactly 99 m."""

    name = "echo_test"

    def subscriptions(self) -> list[Subscription]:
        return [Subscription("fixstream/sensor/*/depth/*", self.on_depth, accepts=(Depth,), monotonic=True)]

    def on_depth(self, key: str, msg: Message) -> list[Output]:
        assert isinstance(msg, Depth)
        if msg.depth_m > 100.0:
            raise InputRejected("too_deep", f"{msg.depth_m} m")
        if msg.depth_m == 99.0:
            raise RuntimeError("simulated bug")
        return [Output(OUT_KEY, msg)]


def _start(svc: Service, router: str) -> tuple[threading.Thread, zenoh.Session]:
    """Run ``svc`` on a thread and wait for its liveliness token; returns the thread and a client session."""
    thread = threading.Thread(target=svc.run, daemon=True)
    thread.start()
    client = open_session(ZenohSettings(mode="client", connect=[router]))
    alive = keys.alive(svc.name, svc.instance)
    assert wait_until(lambda: len(list(client.liveliness().get(alive, timeout=0.5))) == 1)
    return thread, client


@pytest.fixture()
def running(router: str) -> Iterator[tuple[DepthEcho, zenoh.Session]]:
    svc = DepthEcho(ServiceSettings(instance="t1"), ZenohSettings(mode="client", connect=[router]))
    thread, client = _start(svc, router)
    yield svc, client
    svc.stop()
    thread.join(timeout=10)
    assert not thread.is_alive()
    # the liveliness token is gone once the service stopped
    assert wait_until(lambda: len(list(client.liveliness().get(keys.alive(svc.name, svc.instance), timeout=0.5))) == 0)
    client.close()


def _put(client: zenoh.Session, key: str, payload: bytes, encoding: str) -> None:
    client.put(key, payload, encoding=zenoh.Encoding(encoding))


def test_dispatch_reject_and_report(running: tuple[DepthEcho, zenoh.Session]) -> None:
    svc, client = running
    outputs: list[Depth] = []
    diags: list[Diagnostic] = []
    client.declare_subscriber(OUT_KEY, lambda s: outputs.append(codec.decode(s.payload.to_bytes(), str(s.encoding))))  # type: ignore[arg-type]
    client.declare_subscriber(
        keys.diag("echo_test", "t1"),
        lambda s: diags.append(codec.decode(s.payload.to_bytes(), str(s.encoding))),  # type: ignore[arg-type]
    )
    enc = codec.encoding_of(Depth)

    def depth(stamp: int, d: float) -> bytes:
        return codec.encode(Depth(header=Header(stamp_ns=stamp), depth_m=d))

    nan = msgpack.packb({"header": {"stamp_ns": 5}, "depth_m": math.nan})
    sent = [
        (depth(10, 5.0), enc, None),
        (nan, enc, "non_finite"),
        (depth(20, 6.0), enc, None),
        (depth(15, 7.0), enc, "stamp_backwards"),
        (
            codec.encode(Heading(header=Header(stamp_ns=30), heading_rad=1.0)),
            codec.encoding_of(Heading),
            "unexpected_type",
        ),
        (depth(40, 150.0), enc, "too_deep"),
        (depth(50, 99.0), enc, "internal_error"),
        (b"\x93\x01", enc, "bad_msgpack"),
        (depth(60, 8.0), enc, None),
    ]
    for payload, encoding, _ in sent:
        _put(client, IN_KEY, payload, encoding)
    expected_reasons = [r for *_, r in sent if r is not None]
    assert wait_until(lambda: svc.counters.received == len(sent))
    assert wait_until(lambda: len(diags) == len(expected_reasons) and len(outputs) == 3)

    # every good message came out, in order, stamped by the service with its source and a per-key seq
    assert [o.depth_m for o in outputs] == [5.0, 6.0, 8.0]
    assert [o.header.seq for o in outputs] == [0, 1, 2]
    assert {o.header.source for o in outputs} == {"echo_test/t1"}
    assert [o.header.stamp_ns for o in outputs] == [10, 20, 60]  # time comes from the data

    # every rejection was reported once, naming the key and the reason, with running counts
    assert [d.reason for d in diags] == expected_reasons
    assert all(d.key == IN_KEY for d in diags)
    assert diags[-1].counts == {r: 1 for r in expected_reasons}

    # the status queryable tells the same story
    replies = list(client.get(keys.status("echo_test", "t1"), timeout=2.0))
    assert len(replies) == 1 and replies[0].ok is not None
    status = json.loads(replies[0].ok.payload.to_bytes())
    c = status["counters"]
    assert c["received"] == len(sent)
    assert c["accepted"] == 3
    assert c["rejected"] == len(expected_reasons)
    assert c["rejected_by_reason"] == {r: 1 for r in expected_reasons}
    assert c["last_error_key"] == IN_KEY
    assert status["config"]["instance"] == "t1"


def test_process_without_zenoh_counts_rejections() -> None:
    """The decode/dispatch path works in-process too (no session): counts, no crash."""
    svc = DepthEcho(ServiceSettings(instance="t2"), ZenohSettings())
    svc._subs = svc.subscriptions()
    svc.process(IN_KEY, b"\xc1", codec.encoding_of(Depth))  # 0xc1 is never valid msgpack
    svc.process(IN_KEY, b"", "text/plain")
    assert svc.counters.rejected == 2
    assert svc.counters.rejected_by_reason == {"bad_msgpack": 1, "bad_encoding": 1}


def test_run_offline_uses_the_same_path_and_stamps_outputs() -> None:
    svc = DepthEcho(ServiceSettings(instance="t3"), ZenohSettings())
    events = [
        (IN_KEY, Depth(header=Header(stamp_ns=10), depth_m=1.0)),
        (IN_KEY, Depth(header=Header(stamp_ns=5), depth_m=2.0)),  # backwards: rejected
        (IN_KEY, Depth(header=Header(stamp_ns=20), depth_m=150.0)),  # refused by the handler
        (IN_KEY, Depth(header=Header(stamp_ns=30), depth_m=3.0)),
    ]
    out = svc.run_offline(events)
    fixes = [o for o in out if o.key == OUT_KEY]
    diags = [o.msg for o in out if o.key == keys.diag("echo_test", "t3")]
    assert [(f.msg.header.seq, f.msg.header.source, f.msg.depth_m) for f in fixes] == [  # type: ignore[attr-defined]
        (0, "echo_test/t3", 1.0),
        (1, "echo_test/t3", 3.0),
    ]
    assert [d.reason for d in diags] == ["stamp_backwards", "too_deep"]  # type: ignore[attr-defined]


class FlakyDelivery(DepthEcho):
    """A DepthEcho whose hand-over into the inbox fails once, on its second sample."""

    name = "flaky_test"

    def __init__(self, settings: ServiceSettings, zenoh_settings: ZenohSettings) -> None:
        super().__init__(settings, zenoh_settings)
        self.enqueued = 0

    def _enqueue(self, sample: zenoh.Sample) -> None:
        self.enqueued += 1
        if self.enqueued == 2:
            raise RuntimeError("simulated failure in the hand-over")
        super()._enqueue(sample)


def test_a_delivery_thread_outlives_a_failed_hand_over_and_ends_with_the_service(router: str) -> None:
    """Each subscription's samples reach the inbox through a delivery thread (Zenoh's FIFO, then ``try_recv``): a
    sample whose hand-over fails is logged and the next ones are delivered, and the threads end with the service."""
    svc = FlakyDelivery(ServiceSettings(instance="t2"), ZenohSettings(mode="client", connect=[router]))
    thread, client = _start(svc, router)
    outputs: list[float] = []
    client.declare_subscriber(OUT_KEY, lambda s: outputs.append(codec.unpack(s.payload.to_bytes())["depth_m"]))
    pumps = list(svc._delivery.values())
    assert len(pumps) == 2  # the data subscription and the scenario markers'
    assert all(t.is_alive() for t in pumps)
    for i in range(6):
        _put(client, IN_KEY, codec.encode(Depth(header=Header(stamp_ns=10 * (i + 1)), depth_m=float(i))), ENC)
    assert wait_until(lambda: len(outputs) == 5)
    assert outputs == [0.0, 2.0, 3.0, 4.0, 5.0]  # the second sample's hand-over failed; the others came through
    assert svc.counters.received == 5
    svc.stop()
    thread.join(timeout=10)
    assert not thread.is_alive()
    assert not any(t.is_alive() for t in pumps) and not svc._delivery
    client.close()
