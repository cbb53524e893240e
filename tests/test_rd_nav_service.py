"""The rd_nav service adapter without Zenoh (issue 5): settings, keys, equality with the core, and bad input.

The inputs are the demo's (``scenarios/rd_demo.yaml``: the closed loop run with the coordinator in-process), as the
player publishes them to vehicle auv4. Bad input (T-ROB-13 and the digest's §7.4) goes through ``run_offline``, the
service's own decode/validate/dispatch path: NaN and infinity in the sensors and in an arrival time, unknown beacon
id (an unknown node, and a sender outside ``fleet_ids``), a broadcast position off the survey, duplicate, stale and
leaderless packets, a receiver clock step inside a cycle, an implausible sound speed, a DVL sample going back in
time, and the transport's own cases. Each is refused with its reason and reported on diag; the filter goes on, its
particles stay finite, and the fixes after the bad input are as good as before.
"""

from __future__ import annotations

import math
from collections import Counter
from functools import cache
from typing import Any

import numpy as np
import pytest
from conftest import REPO
from stack_support import Raw, announced, delivered, framed, offline_on_bytes, on_key, raw, without_source_seq

from schemas import (
    AcousticArrival,
    Attitude,
    Depth,
    Diagnostic,
    Message,
    ScenarioMarker,
    SoundSpeed,
    SpeedLog,
    Truth,
)
from schemas.rd_nav import RdNavFix, TdoaCycle
from services.player.scenario import Scenario, load_scenario
from services.player.simulators import Event
from services.player.timeline import scenario_events
from services.rd_nav.core import RdNavCore
from services.rd_nav.service import (
    RdNavService,
    RdNavSettings,
    build,
    cycle_key,
    ekf_key,
    fix_key,
    input_expr,
    output_key,
)
from shared import codec, keys

DEMO = REPO / "scenarios" / "rd_demo.yaml"
AUV = "auv4"
MODEM = keys.sensor(AUV, "acoustic", "modem0")
DVL = keys.sensor(AUV, "dvl", "dvl0")
AHRS = keys.sensor(AUV, "attitude", "ahrs0")
DEPTH = keys.sensor(AUV, "depth", "press0")
SVS = keys.sensor(AUV, "sound_speed", "svs0")
DIAG = keys.diag("rd_nav", "bad1")
FLEET = ["auv1", "auv2", "auv3", "auv4", "auv5"]


@cache
def demo() -> tuple[Scenario, tuple[Event, ...]]:
    scenario = load_scenario(DEMO)
    return scenario, tuple(scenario_events(scenario))


def make_service(instance: str = AUV, **settings: Any) -> RdNavService:
    return RdNavService(RdNavSettings(instance=instance, **settings))


def vehicle_feed(svc: RdNavService) -> list[tuple[str, Message]]:
    scenario, events = demo()
    return delivered(svc, framed(scenario, [(e.key, e.msg) for e in events]))


def truth_ne(events: tuple[Event, ...] | list[Event], auv: str) -> dict[int, tuple[float, float]]:
    """Truth of a vehicle by stamp, as base NED (north, east) (the simulator publishes [east, north, up])."""
    out = {}
    for e in events:
        if e.key == keys.truth(auv) and isinstance(e.msg, Truth):
            out[e.stamp_ns] = (e.msg.position_m[1], e.msg.position_m[0])
    return out


def cycle_errors(fixes: list[Message], truth: dict[int, tuple[float, float]]) -> list[tuple[int, float]]:
    out = []
    for f in fixes:
        if isinstance(f, RdNavFix) and f.estimator == "PF" and f.kind == "CYCLE":
            n, e = truth[f.header.stamp_ns]
            out.append((f.header.stamp_ns, math.hypot(f.estimate.mean[0] - n, f.estimate.mean[1] - e)))
    return out


# ------------------------------------------------------------------------------------------------ basics -------
def test_settings_keys_and_build(monkeypatch: pytest.MonkeyPatch) -> None:
    for k in [k for k in list(__import__("os").environ) if k.startswith("FIXSTREAM_")]:
        monkeypatch.delenv(k)
    monkeypatch.setenv("FIXSTREAM_RD_NAV_INSTANCE", "auv7")
    monkeypatch.setenv("FIXSTREAM_RD_NAV_N_PARTICLES", "300")
    monkeypatch.setenv("FIXSTREAM_RD_NAV_FLEET_IDS", '["auv1", "auv2"]')
    svc = build()
    assert svc.auv_id == "auv7" and svc.core_config.auv_id == "auv7"
    assert svc.core_config.n_particles == 300 and svc.core_config.fleet_ids == ["auv1", "auv2"]
    assert [s.key_expr for s in svc.subscriptions()] == ["fixstream/sensor/auv7/**"] == [input_expr("auv7")]
    assert fix_key("auv7") == "fixstream/fix/rd/auv7"
    assert ekf_key("auv7") == "fixstream/fix/rd/auv7/ekf" and cycle_key("auv7") == "fixstream/fix/rd/auv7/cycle"
    monkeypatch.setenv("FIXSTREAM_RD_NAV_AUV_ID", "auv9")
    assert build().auv_id == "auv9"
    monkeypatch.setenv("FIXSTREAM_RD_NAV_AUV_ID", "a/b")
    with pytest.raises(ValueError, match="key chunk"):
        build()


def test_service_equals_the_core_in_process_and_navigates_the_demo() -> None:
    svc = make_service()
    feed = vehicle_feed(svc)
    out = svc.run_offline(feed)
    # the core on the same messages, its outputs filed on the service's keys
    core = RdNavCore(svc.core_config)
    expected: list[tuple[str, Message]] = []
    for _, msg in feed[1:-1]:
        expected += [(output_key(AUV, m), m) for m in core.step(msg)]
    assert [o.key for o in out if not isinstance(o.msg, Diagnostic)] == [k for k, _ in expected]
    got = without_source_seq([o.msg for o in out if not isinstance(o.msg, Diagnostic)])
    assert got == without_source_seq([m for _, m in expected])
    assert all(o.msg.header.source == f"rd_nav/{AUV}" for o in out)
    # per key seq 0, 1, 2, ...
    for key in {o.key for o in out}:
        assert [m.header.seq for m in on_key(out, key)] == list(range(len(on_key(out, key))))
    # it navigates: every cycle of the 120 s used but the one lost to the role swap, errors of a metre or two
    _, events = demo()
    errs = cycle_errors(on_key(out, fix_key(AUV)), truth_ne(events, AUV))
    assert len(errs) == 11
    assert max(e for _, e in errs) < 4.0 and math.sqrt(np.mean([e * e for _, e in errs])) < 2.0
    cycles = [m for m in on_key(out, cycle_key(AUV)) if isinstance(m, TdoaCycle)]
    assert len(cycles) == 11 and len(on_key(out, ekf_key(AUV))) == 11
    assert [c.reject_reason for c in cycles if c.status == "REJECTED"] == ["NO_VALID_FOLLOWER"]  # the swap
    assert svc.counters.rejected == 0 and svc.sessions == 2  # the end marker started a fresh core
    assert not svc.core.initialised


def test_publish_options_and_the_departing_vehicle() -> None:
    quiet = make_service(publish_ekf=False, publish_cycles=False, report_events=False)
    out = quiet.run_offline(vehicle_feed(quiet))
    assert {o.key for o in out} == {fix_key(AUV)}
    assert quiet.events["cycle_no_valid_follower"] == 1  # counted though not reported
    # auv3 is docked (a beacon) until the coordinator lets it go, then navigates from its node
    svc3 = make_service("auv3")
    out3 = svc3.run_offline(vehicle_feed(svc3))
    fixes = [m for m in on_key(out3, fix_key("auv3")) if isinstance(m, RdNavFix)]
    assert fixes and min(f.header.stamp_ns for f in fixes) > 30e9  # only after it departed
    _, events = demo()
    errs = cycle_errors(fixes, truth_ne(events, "auv3"))
    assert len(errs) >= 7 and max(e for _, e in errs) < 4.0
    # replies of the cycle in flight when it undocked came without their leader packet: refused and reported
    assert set(svc3.counters.rejected_by_reason) <= {"no_leader"}


# ------------------------------------------------------------------------------------------------ bad input ----
def _arrival(m: Message) -> AcousticArrival:
    assert isinstance(m, AcousticArrival)
    return m


def _with_packet(a: AcousticArrival, **update: Any) -> AcousticArrival:
    return a.model_copy(update={"packet": a.packet.model_copy(update=update)})


def bad_items(feed: list[tuple[str, Message]]) -> tuple[list[Raw], Counter[str], int]:
    """The vehicle's feed with every bad case inserted after 45 s (the filter tracking), the expected refusals, and
    the stamp of the receiver clock step (+0.5 s from there on, inside a cycle)."""
    expected: Counter[str] = Counter()
    arrivals = [(i, _arrival(m)) for i, (k, m) in enumerate(feed) if k == MODEM]
    leaders = [(i, a) for i, a in arrivals if a.packet.kind == "LEADER" and a.header.stamp_ns > 45e9]
    i_lead, lead = leaders[0]  # a cycle to hurt
    i_next, _ = leaders[1]
    followers = [a for i, a in arrivals if a.packet.kind == "FOLLOWER" and i < i_lead]
    last_reply = followers[-1]  # of the previous cycle, closed by now
    stepped = leaders[3][1]
    step_at = stepped.header.stamp_ns + 300_000_000  # 0.3 s after a later leader: before its replies
    replies = [a for _, a in arrivals if a.packet.kind == "FOLLOWER" and a.packet.cycle_seq == stepped.packet.cycle_seq]
    expected["stale_packet"] += len(replies) - 1  # the first reply shows the step and closes the cycle; the rest
    items: list[Raw] = []
    assert isinstance(feed[-1][1], ScenarioMarker) and feed[-1][1].event == "end"
    for i, (key, msg) in enumerate(feed[:-1]):  # the end marker is rebuilt below
        if key == MODEM and msg.header.stamp_ns > step_at:
            a = _arrival(msg)
            msg = a.model_copy(update={"t_rx_local_s": a.t_rx_local_s + 0.5})
        items.append(raw(key, msg))
        if i == i_lead:
            later = lead.header.model_copy(update={"stamp_ns": lead.header.stamp_ns + 1000})
            nan_dvl = SpeedLog.model_construct(header=later, v_forward_mps=math.nan, v_starboard_mps=0.0)
            items.append(raw(DVL, nan_dvl))
            items.append(
                raw(AHRS, Attitude.model_construct(header=later, heading_rad=math.nan, pitch_rad=0.0, roll_rad=0.0))
            )
            items.append(raw(DEPTH, Depth.model_construct(header=later, depth_m=math.inf)))
            expected["non_finite"] += 3
            items.append(raw(MODEM, lead.model_copy(update={"header": later, "t_rx_local_s": math.nan})))
            expected["non_finite"] += 1
            items.append(raw(MODEM, _with_packet(lead, node_id="n9").model_copy(update={"header": later})))
            expected["unknown_node"] += 1
            stranger = _with_packet(lead, sender_id="auv9", leader_id="auv9")
            items.append(raw(MODEM, stranger.model_copy(update={"header": later})))
            expected["unknown_sender"] += 1
            off = [lead.packet.pos_ned_m[0] + 5.0, *lead.packet.pos_ned_m[1:]]
            items.append(raw(MODEM, _with_packet(lead, pos_ned_m=off).model_copy(update={"header": later})))
            expected["beacon_pos_mismatch"] += 1
            items.append(raw(MODEM, lead.model_copy(update={"header": later})))  # the same leader packet again
            expected["duplicate"] += 1
            items.append(raw(MODEM, last_reply.model_copy(update={"header": later})))  # a reply to a closed cycle
            expected["stale_packet"] += 1
            orphan = last_reply.model_copy(update={"packet": last_reply.packet.model_copy(update={"cycle_seq": 999})})
            items.append(raw(MODEM, orphan.model_copy(update={"header": later})))
            expected["no_leader"] += 1
            items.append(raw(SVS, SoundSpeed(header=later, c_mps=1700.0, sigma_c_mps=0.3)))
            expected["implausible_sound_speed"] += 1
            early = lead.header.model_copy(update={"stamp_ns": lead.header.stamp_ns - 2_000_000_000})
            items.append(raw(DVL, SpeedLog(header=early, v_forward_mps=1.5, v_starboard_mps=0.0)))
            expected["stamp_backwards"] += 1
            items.append((DVL, b"\xc1", codec.encoding_of(SpeedLog)))
            expected["bad_msgpack"] += 1
            items.append((DVL, b"\x93\x01\x02\x03", codec.encoding_of(SpeedLog)))
            expected["wrong_type"] += 1
            items.append(raw(DVL, Truth(header=later, platform=AUV, position_m=[0.0, 0.0, 0.0])))
            expected["unexpected_type"] += 1
        if i == i_next:
            items.append(raw(MODEM, msg))  # the same LEADER packet twice: its cycle is open
            expected["duplicate"] += 1
    # the end marker counts the player's own messages per key, as the player's does: a service ends the run only
    # once all of them have arrived (bad payloads with no header of the player's count for nobody)
    end = feed[-1][1]
    end = end.model_copy(update={"published": dict(announced(items, end.header.source))})
    items.append(raw(feed[-1][0], end))
    return items, expected, step_at


def offline_twin(items: list[Raw], instance: str = "bad1") -> RdNavService:
    twin = make_service(instance, auv_id=AUV, fleet_ids=FLEET)
    offline_on_bytes(twin, items)
    return twin


def check_bad_input_run(twin: RdNavService, expected: Counter[str], step_at: int) -> None:
    """What the bad-input run must show (shared with the test over a real router)."""
    assert twin.counters.rejected_by_reason == expected
    assert twin.counters.received == twin.counters.accepted + twin.counters.rejected
    diags = [o.msg for o in twin.outbox if isinstance(o.msg, Diagnostic)]
    reasons = Counter(d.reason for d in diags)
    for reason, n in expected.items():
        assert reasons[reason] == n, reason
    assert "internal_error" not in reasons
    # the clock step inside a cycle: that cycle discarded, no re-initialisation
    assert twin.events["cycle_clock_jump"] == 1 and twin.events["reinit"] == 0
    fixes = [o.msg for o in twin.outbox if o.key == fix_key(AUV) and isinstance(o.msg, RdNavFix)]
    jump = [f for f in fixes if f.kind == "CYCLE" and f.reject_reason == "CLOCK_JUMP"]
    assert len(jump) == 1 and jump[0].header.stamp_ns < step_at
    # the fixes after the bad input are as good as before it, and the cycles after the step are used
    _, events = demo()
    errs = cycle_errors(fixes, truth_ne(events, AUV))
    assert max(e for _, e in errs) < 4.0
    after = [f for f in fixes if f.kind == "CYCLE" and f.header.stamp_ns > step_at + 5e9]
    assert after and all(f.cycle_status == "USED" for f in after)
    # the sound-speed fallback was flagged on the cycle that followed it
    assert any("SOUND_SPEED_FALLBACK" in f.flags for f in fixes if f.kind == "CYCLE")


def test_bad_input_is_refused_reported_and_the_filter_goes_on() -> None:
    svc = make_service("bad1", auv_id=AUV, fleet_ids=FLEET)
    feed = vehicle_feed(svc)
    items, expected, step_at = bad_items(feed)
    twin = offline_twin(items)
    check_bad_input_run(twin, expected, step_at)
    # never a NaN in the particle set; covariances symmetric positive definite (the state before the reset)
    twin2 = make_service("bad2", auv_id=AUV, fleet_ids=FLEET, reset_on_scenario_end=False)
    twin2.run_offline([])
    for key, payload, encoding in items:
        twin2.process(key, payload, encoding, rx_time_ns=0)
        if twin2.core.initialised:
            pf = twin2.core.pf
            assert np.isfinite(pf.X).all() and np.isfinite(pf.w).all()
    _, cov = twin2.core.pf.estimate()
    assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
    for o in twin2.outbox:
        if isinstance(o.msg, RdNavFix):
            assert all(math.isfinite(v) for v in [*o.msg.estimate.mean, o.msg.depth_m])
