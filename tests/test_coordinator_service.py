"""The coordinator service adapter without Zenoh (issue 5): settings, keys, one reply per input, bad input.

The inputs are the demo's uplink (``scenarios/rd_demo.yaml``: node table, the vehicles' status reports and the
beacons' packets heard at the base, with the coordinator in the loop in-process), framed by the player's markers.
"""

from __future__ import annotations

import math
import os
from collections import Counter

import pytest
from stack_support import delivered, framed, offline_on_bytes, on_key, raw
from test_rd_nav_service import demo

from schemas import AcousticArrival, BeaconTable, Diagnostic, Header, Message, Truth
from schemas.acoustic import Beacon
from schemas.rd_nav import BeaconAssignment, CoordinatorReply, DepartureGrant, VehicleStatus
from services.coordinator.config import CoordinatorConfig
from services.coordinator.core import CoordinatorCore
from services.coordinator.protocol import CoordinatorProtocol, config_digest
from services.coordinator.service import (
    CoordinatorService,
    CoordinatorSettings,
    assignment_key,
    build,
    grant_key,
    reply_key,
    uplink_expr,
    uplink_key,
)
from services.player.simulators import Event
from services.rd_nav.simulator import LocalCoordinator
from shared import codec

GROUP = "group1"


def make_service(instance: str = GROUP, **settings: object) -> CoordinatorService:
    return CoordinatorService(CoordinatorSettings(instance=instance, **settings))  # type: ignore[arg-type]


def uplink_feed(svc: CoordinatorService) -> list[tuple[str, Message]]:
    scenario, events = demo()
    return delivered(svc, framed(scenario, [(e.key, e.msg) for e in events]))


def test_settings_keys_and_build(monkeypatch: pytest.MonkeyPatch) -> None:
    for k in [k for k in os.environ if k.startswith("FIXSTREAM_")]:
        monkeypatch.delenv(k)
    monkeypatch.setenv("FIXSTREAM_COORDINATOR_INSTANCE", "g7")
    monkeypatch.setenv("FIXSTREAM_COORDINATOR_TAU_SLOTS_S", "[0.5, 4.0]")
    svc = build()
    assert svc.group == "g7" and svc.protocol.config.tau_slots_s == [0.5, 4.0]
    assert svc.protocol.digest == config_digest(CoordinatorConfig(tau_slots_s=[0.5, 4.0]))
    assert svc.protocol.digest != config_digest(CoordinatorConfig())
    assert [s.key_expr for s in svc.subscriptions()] == ["fixstream/group/g7/uplink/**"] == [uplink_expr("g7")]
    assert assignment_key("g7") == "fixstream/group/g7/assignment"
    assert grant_key("g7", "auv3") == "fixstream/group/g7/grant/auv3"
    assert reply_key("g7") == "fixstream/group/g7/reply"
    assert uplink_key("g7", "auv3", "status") == "fixstream/group/g7/uplink/auv3/status"
    monkeypatch.setenv("FIXSTREAM_COORDINATOR_GROUP", "g8")
    assert build().group == "g8"
    monkeypatch.setenv("FIXSTREAM_COORDINATOR_MIN_BEACONS", "1")
    with pytest.raises(ValueError, match="min_beacons"):
        build()


def test_one_reply_per_input_and_the_same_decisions_as_in_process() -> None:
    svc = make_service()
    feed = uplink_feed(svc)
    out = svc.run_offline(feed)
    inputs = feed[1:-1]
    replies = [m for m in on_key(out, reply_key(GROUP)) if isinstance(m, CoordinatorReply)]
    assert len(replies) == len(inputs)
    assert [(r.input_key, r.input_source, r.input_seq, r.header.stamp_ns) for r in replies] == [
        (k, m.header.source, m.header.seq, m.header.stamp_ns) for k, m in inputs
    ]
    assert all(r.rejected is None and r.config_digest == svc.protocol.digest for r in replies)
    # the decisions published = those in the replies = the in-process twin's (the simulation's offline driver)
    assignments = on_key(out, assignment_key(GROUP))
    grants = on_key(out, grant_key(GROUP, "auv3"))
    strip = {"header"}
    assert [a.model_dump(exclude=strip) for a in assignments] == [
        a.model_dump(exclude=strip) for r in replies for a in r.assignments
    ]
    assert [g.model_dump(exclude=strip) for g in grants] == [
        g.model_dump(exclude=strip) for r in replies for g in r.grants
    ]
    twin = LocalCoordinator(GROUP, CoordinatorConfig())
    local = twin(_events(inputs))
    assert [r.model_dump(exclude={"header", "input_source", "input_seq"}) for r in local] == [
        r.model_dump(exclude={"header", "input_source", "input_seq"}) for r in replies
    ]
    # the demo's story: three epochs, the last one without auv3, then its grant while 3 others remain
    assert [a.epoch for a in assignments if isinstance(a, BeaconAssignment)] == [1, 2, 3]
    last = assignments[-1]
    assert isinstance(last, BeaconAssignment) and "auv3" not in (last.leader_id, *last.follower_ids)
    assert len(grants) == 1 and isinstance(grants[0], DepartureGrant) and grants[0].epoch == 3
    assert grants[0].header.stamp_ns > last.header.stamp_ns
    assert svc.counters.rejected == 0 and svc.sessions == 2
    assert svc.decisions == {"assignment": 3, "grant": 1}


def _events(feed: list[tuple[str, Message]]) -> list[Event]:
    return [Event(m.header.stamp_ns, k, m) for k, m in feed]


def _status(t: float, auv: str, event: str, node: str | None = None, seq: int = 0) -> VehicleStatus:
    header = Header(stamp_ns=round(t * 1e9), source="player/default", seq=seq)
    return VehicleStatus.model_validate({"header": header, "auv_id": auv, "event": event, "node_id": node})


def test_refused_inputs_get_a_reply_and_are_reported() -> None:
    svc = make_service(report_alarms=True)
    st = uplink_key(GROUP, "auv1", "status")
    nodes = uplink_key(GROUP, "base", "nodes")
    heard = uplink_key(GROUP, "base", "acoustic")
    _, events = demo()
    table = next(e.msg for e in events if e.key == nodes)
    arrival = next(e.msg for e in events if e.key == heard)
    assert isinstance(table, BeaconTable) and isinstance(arrival, AcousticArrival)
    stranger = arrival.model_copy(update={"packet": arrival.packet.model_copy(update={"sender_id": "auv9"})})
    bad_table = BeaconTable.model_construct(
        header=Header(stamp_ns=0),
        beacons=[Beacon.model_construct(beacon_id="n9", x_east_m=math.nan, y_north_m=0.0, depth_m=100.0)],
    )
    items = [
        raw(nodes, table),
        raw(st, _status(1.0, "auv1", "DOCKED", "n1")),
        raw(st, _status(2.0, "auv1", "DOCKED", "n9", seq=1)),  # a node not in the table
        raw(st, _status(1e6, "auv8", "SERVICE_DONE", seq=2)),  # not docked; its far-future stamp must not count
        raw(heard, stranger),  # a packet from a vehicle the base never heard of
        raw(st, Truth(header=Header(stamp_ns=3), platform="x", position_m=[0.0, 0.0, 0.0])),  # wrong type
        raw(nodes, bad_table),  # NaN: refused by the codec, nothing to answer
        (st, b"\xc1", codec.encoding_of(VehicleStatus)),  # not msgpack
        raw(st, _status(3.0, "auv2", "DOCKED", "n2", seq=3)),
        raw(st, _status(4.0, "auv3", "DOCKED", "n3", seq=4)),
    ]
    offline_on_bytes(svc, items)
    expected = Counter(
        {
            "unknown_node": 1,
            "not_docked": 1,
            "unknown_sender": 1,
            "unexpected_type": 1,
            "non_finite": 1,
            "bad_msgpack": 1,
        }
    )
    assert svc.counters.rejected_by_reason == expected
    replies = [o.msg for o in svc.outbox if isinstance(o.msg, CoordinatorReply)]
    # every decodable input is answered, the refused ones too (the undecodable cannot be named)
    refusals = ["unknown_node", "not_docked", "unknown_sender", "unexpected_type"]
    assert [r.rejected for r in replies] == [None, None, *refusals, None, None]
    diags = Counter(o.msg.reason for o in svc.outbox if isinstance(o.msg, Diagnostic))
    assert diags == expected
    # a refusal changes nothing: auv8 unknown, the clock not moved to t = 1e6 s (no beacon timed out)
    core = svc.protocol.core
    assert "auv8" not in core.vehicles and core.t < 10.0
    assert sorted(core.beacons()) == ["auv1", "auv2", "auv3"]
    assert core.assignment is not None and core.alarms["beacon_timeout"] == 0
    assert svc.status_extra()["active_set"] and svc.status_extra()["epoch"] == 1


def test_alarms_are_reported_as_events() -> None:
    svc = make_service()
    _, events = demo()
    nodes = uplink_key(GROUP, "base", "nodes")
    table = next(e.msg for e in events if e.key == nodes)
    st = uplink_key(GROUP, "auvX", "status")
    items = [raw(nodes, table)]
    for k, (auv, node) in enumerate((("auv1", "n1"), ("auv2", "n2"), ("auv3", "n3"))):
        items.append(raw(st, _status(float(k), auv, "DOCKED", node, seq=k)))
    items.append(raw(st, _status(100.0, "auv1", "HEARTBEAT", "n1", seq=3)))  # 100 s without hearing the others
    offline_on_bytes(svc, items)
    diags = [o.msg for o in svc.outbox if isinstance(o.msg, Diagnostic)]
    assert {d.reason for d in diags} >= {"beacon_timeout"}
    assert all(d.level in ("warning", "error") for d in diags)
    assert svc.alarms["beacon_timeout"] >= 2 and svc.counters.rejected == 0
    assert isinstance(svc.protocol.core, CoordinatorCore)


def test_protocol_never_raises_and_names_the_input() -> None:
    proto = CoordinatorProtocol(GROUP)
    bad = _status(5.0, "auv1", "SERVICE_DONE")
    ans = proto.handle("k/x", bad)
    assert ans.rejected is not None and ans.rejected.reason == "not_docked"
    assert ans.reply.rejected == "not_docked" and ans.reply.input_key == "k/x" and ans.reply.epoch == 0
    assert ans.decisions == [] and ans.reply.header.stamp_ns == bad.header.stamp_ns


def test_a_vehicle_id_that_cannot_name_a_key_is_refused_before_it_enters_the_registry() -> None:
    """Found by the 20,000-payload fuzz campaign: a DOCKED status from ``"not this"`` (a valid string, not a key
    chunk) entered the registry, and the grant later decided for it could not be keyed (an internal error)."""
    svc = make_service()
    st = uplink_key(GROUP, "auv1", "status")
    nodes = uplink_key(GROUP, "base", "nodes")
    _, events = demo()
    table = next(e.msg for e in events if e.key == nodes)
    items = [
        raw(nodes, table),
        *(raw(st, _status(1.0 + i, f"auv{i + 1}", "DOCKED", f"n{i + 1}", seq=i)) for i in range(3)),
        raw(st, _status(5.0, "not this", "DOCKED", "n1", seq=3)),
        raw(st, _status(6.0, "auv1", "SERVICE_DONE", seq=4)),
        raw(st, _status(7.0, "not this", "SERVICE_DONE", seq=5)),
    ]
    offline_on_bytes(svc, items)
    assert svc.counters.rejected_by_reason == Counter({"invalid_auv_id": 2})
    assert "not this" not in svc.protocol.core.vehicles
    for o in svc.outbox:  # every decision it published is keyed by a vehicle it knows
        if isinstance(o.msg, DepartureGrant):
            assert o.msg.auv_id in {"auv1", "auv2", "auv3"} and o.key.endswith(o.msg.auv_id)
