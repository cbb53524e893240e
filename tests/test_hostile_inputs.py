"""Property-based tests (Hypothesis) of the wire codec and of every estimator service's input path.

A hostile or careless client can put anything on a service's keys: random bytes, msgpack that is no message,
messages valid against the JSON Schema with extreme values, real messages with stamps at the bounds or going
backwards, duplicates, markers from foreign sources. For every estimator service:

* ``process`` never raises (nothing a payload does ends the process), and the counters add up: every sample
  received is accepted or rejected, every rejection has a reason;
* a run full of such input, ended by the player's end marker, does not bend the next run: the next run's fixes
  equal those of a fresh service on the same clean run (source and seq of the outputs aside: the junk run's own
  outputs advanced the per-key seq).

The default profile runs a few dozen examples per service; ``HYPOTHESIS_PROFILE=hostile-long`` (with
``-m slow``) runs the long campaign.
"""

from __future__ import annotations

import math
import os
from functools import cache
from typing import Any

import msgpack
import pytest
from conftest import REPO
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schema_strategy import message_dicts
from stack_support import build_composed, delivered, framed, scenario_feed, without_source_seq

from schemas import MODELS, Diagnostic, Header, Message, ScenarioMarker
from schemas.base import MAX_STAMP_NS
from services.player.scenario import load_scenario
from shared import codec, keys
from shared.service import Service

settings.register_profile(
    "hostile-default",
    max_examples=25,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
settings.register_profile("hostile-long", parent=settings.get_profile("hostile-default"), max_examples=1000)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "hostile-default"))

#: estimator service -> (its compose service, the demo scenario that feeds it)
SERVICES: dict[str, tuple[str, str]] = {
    "attitude": ("attitude-r1", "attitude_demo"),
    "lbl_nav": ("lbl_nav-lbl1", "lbl_nav_demo"),
    "pcl_tracker": ("pcl_tracker-rx1-fm", "pcl_tracker_demo"),
    "rd_nav": ("rd_nav-auv4", "rd_demo"),
    "coordinator": ("coordinator-group1", "rd_demo"),
    "terrain_nav": ("terrain_nav-tan1", "terrain_nav_demo"),
}


def build(name: str) -> Service:
    return build_composed(SERVICES[name][0], name)


@cache
def clean_run(name: str) -> tuple[list[tuple[str, Message]], dict[str, list[Message]]]:
    """The service's share of its demo scenario, framed by the player's markers, and a fresh service's fixes."""
    sc = load_scenario(REPO / "scenarios" / f"{SERVICES[name][1]}.yaml")
    svc = build(name)
    events = framed(sc, delivered(svc, scenario_feed(sc)))
    return events, fixes(svc.run_offline(events))


def fixes(outputs: list[Any]) -> dict[str, list[Message]]:
    """What the service published per key, diagnostics aside, with source and seq blanked."""
    by_key: dict[str, list[Message]] = {}
    for o in outputs:
        if not isinstance(o.msg, Diagnostic):
            by_key.setdefault(o.key, []).append(o.msg)
    return {k: without_source_seq(v) for k, v in by_key.items()}


# --- payload strategies -------------------------------------------------------------------------------------------

_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**64 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=40),
    st.binary(max_size=40),
)
_objects = st.recursive(
    _scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=6), st.dictionaries(st.text(max_size=12), inner, max_size=6)),
    max_leaves=30,
)


def _packb(obj: Any) -> bytes:
    try:
        return msgpack.packb(obj, use_bin_type=True)  # type: ignore[no-any-return]
    except (OverflowError, ValueError, TypeError):
        return b"\xc1"


def _with_header(obj: Any, **changes: Any) -> Any:
    if isinstance(obj, dict) and isinstance(obj.get("header"), dict):
        return {**obj, "header": {**obj["header"], **changes}}
    return obj


@st.composite
def hostile_item(draw: st.DrawFn, name: str) -> tuple[str, bytes, str]:
    """One sample on one of the keys the service listens to (or its scenario key)."""
    events, _ = clean_run(name)
    data = [(k, m) for k, m in events if not isinstance(m, ScenarioMarker)]
    key, real = draw(st.sampled_from(data))
    model = type(real).__name__
    enc = codec.encoding_of(type(real))
    kind = draw(st.sampled_from(["bytes", "msgpack", "schema", "extreme_stamp", "foreign_marker", "other_model"]))
    if kind == "bytes":
        return key, draw(st.binary(max_size=300)), draw(st.sampled_from([enc, "application/octet-stream", ""]))
    if kind == "msgpack":
        return key, _packb(draw(_objects)), enc
    if kind == "schema":  # valid against the message's JSON Schema, values drawn to the bounds
        obj = draw(message_dicts(model))
        return key, _packb(obj), enc
    if kind == "extreme_stamp":  # a real message at the stamp bounds, or back in time, maybe from the player
        obj = codec.unpack(codec.encode(real))
        stamp = draw(st.sampled_from([0, 1, MAX_STAMP_NS, MAX_STAMP_NS + 1, 2**63 - 1, 2**64 - 1, -1]))
        seq = draw(st.sampled_from([0, 2**63 - 1, 2**64 - 1]))
        source = draw(st.sampled_from(["player/default", "evil", ""]))
        return key, _packb(_with_header(obj, stamp_ns=stamp, seq=seq, source=source)), enc
    if kind == "foreign_marker":
        marker = ScenarioMarker(
            header=Header(stamp_ns=draw(st.integers(0, MAX_STAMP_NS)), source=draw(st.sampled_from(["evil", ""]))),
            event=draw(st.sampled_from(["start", "end"])),
            scenario="x",
            seed=0,
            published={},
        )
        return keys.scenario("x"), codec.encode(marker), codec.encoding_of(ScenarioMarker)
    other = draw(st.sampled_from(sorted(MODELS)))  # a valid message of another type on this key
    return key, _packb(draw(message_dicts(other))), codec.encoding_of(MODELS[other])


def run_junk(svc: Service, items: list[tuple[str, bytes, str]]) -> None:
    """A run of the player's that carried only ``items``: its start marker, the items, its end marker."""
    svc.run_offline([])  # declares the subscriptions
    svc.process(keys.scenario("junk"), codec.encode(_marker("start")), codec.encoding_of(ScenarioMarker))
    for key, payload, encoding in items:
        svc.process(key, payload, encoding, rx_time_ns=0)
    svc.process(keys.scenario("junk"), codec.encode(_marker("end")), codec.encoding_of(ScenarioMarker))


def _marker(event: str) -> ScenarioMarker:
    header = Header(stamp_ns=0, source="player/default", seq=0 if event == "start" else 1)
    return ScenarioMarker(header=header, event="start" if event == "start" else "end", scenario="junk", seed=0)


def _check_counters(svc: Service, sent: int) -> None:
    c = svc.counters
    assert c.received == sent + 2  # the items and the two markers
    assert c.received == c.accepted + c.rejected, c.as_dict()
    assert c.rejected == sum(c.rejected_by_reason.values())
    assert c.publish_failed == 0 and "internal_error" not in c.rejected_by_reason, c.as_dict()


@pytest.mark.parametrize("name", sorted(SERVICES))
def test_hostile_input_never_kills_a_service_nor_bends_its_next_run(name: str) -> None:
    events, reference = clean_run(name)
    assert reference, f"{name}: the clean run publishes nothing"

    @given(st.lists(hostile_item(name), min_size=1, max_size=30))
    def check(items: list[tuple[str, bytes, str]]) -> None:
        svc = build(name)
        run_junk(svc, items)
        _check_counters(svc, len(items))
        assert fixes(svc.run_offline(events)) == reference

    check()


def _start_then_rest(svc: Service, events: list[tuple[str, Message]]) -> dict[str, list[Any]]:
    """The run of ``events`` (framed) on ``svc``: its start marker through ``process`` (what it returns, a fresh
    core's announcement, is the start's, not the run's), then the rest; the run's fixes, :func:`renumbered`."""
    key, start = events[0]
    assert isinstance(start, ScenarioMarker) and start.event == "start"
    svc.process(key, codec.encode(start), codec.encoding_of(ScenarioMarker), rx_time_ns=0)
    return renumbered(fixes(svc.run_offline(events[1:])))


def renumbered(by_key: dict[str, list[Message]]) -> dict[str, list[Any]]:
    """The fixes as plain data, PCL track ids numbered by first appearance (a tracker's ids keep increasing from
    one run to the next, docs/pcl_tracker.md, so a run's ids depend on the runs before it)."""
    ids: dict[int, int] = {}
    out: dict[str, list[Any]] = {}
    for key, msgs in by_key.items():
        dumped = []
        for m in msgs:
            d = m.model_dump()
            for track in d.get("tracks") or ():
                if isinstance(track, dict) and "track_id" in track:
                    track["track_id"] = ids.setdefault(track["track_id"], len(ids) + 1)
            dumped.append(d)
        out[key] = dumped
    return out


@pytest.mark.parametrize("name", sorted(SERVICES))
def test_input_between_two_runs_never_bends_the_next_one(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Found by a new user's audit: one schema-valid message that came after a run's end (a replay of some keys, a
    late publisher, anyone) set the fresh core's clock or state, and the next run lost most of its fixes to
    ``stamp_backwards`` (terrain_nav: 0 of 17). Items of every kind, the run's own messages at its end among them,
    arrive between a clean run and the next; the next run's fixes equal a fresh service's, and the drop is counted.
    (The player's own inputs count as strays once older than the window; here the window is 0.)"""
    events, reference = clean_run(name)
    monkeypatch.setattr(Service, "stray_window_s", 0.0)
    data = [(k, m) for k, m in events if not isinstance(m, ScenarioMarker)]
    # the run's last three messages again, as new ones (a duplicate seq would be refused before the core)
    own_last = [
        (k, codec.encode_stamped(m, m.header.source, m.header.seq + 10_000), codec.encoding_of(type(m)))
        for k, m in data[-3:]
    ]

    @settings(max_examples=8)  # a clean run and the next per example; the long profile keeps its own count
    @given(st.lists(hostile_item(name), max_size=20), st.booleans())
    def check(items: list[tuple[str, bytes, str]], with_own: bool) -> None:
        svc = build(name)
        svc.run_offline(events)  # a clean run: it ends, a fresh core waits for the next
        sent = [*items, *(own_last if with_own else [])]
        for key, payload, encoding in sent:
            svc.process(key, payload, encoding, rx_time_ns=0)
        taken = svc._taken_since_new_run > 0  # what reached the core (refused before it, or ignored: did not)
        assert _start_then_rest(svc, events) == renumbered(reference)
        assert svc.stray_resets == int(taken)
        if with_own:
            assert svc.stray_resets == 1

    check()


@pytest.mark.parametrize("name", ["terrain_nav", "attitude"])
def test_a_runs_own_first_samples_taken_before_its_start_marker_are_kept(name: str) -> None:
    """The marker has a subscription of its own, so a run's first samples can be taken before it: within the window
    they are the run's, and kept. The reference: the same service fed the run in order. The control: with a window
    of 0 they count as strays and the run differs."""
    events, reference = clean_run(name)
    svc = build(name)
    svc.run_offline(events)
    first = len(svc.outbox)
    early = events[1:4]  # the run's first three inputs, ahead of their marker
    for key, msg in early:
        svc.process(key, codec.encode(msg), codec.encoding_of(type(msg)), rx_time_ns=0)
    start_key, start = events[0]
    svc.process(start_key, codec.encode(start), codec.encoding_of(ScenarioMarker), rx_time_ns=0)
    svc.run_offline(events[4:])
    assert fixes(svc.outbox[first:]) == reference and svc.stray_resets == 0
    # the control: with no window, the same early samples are strays, dropped, and the run differs
    control = build(name)
    control.stray_window_s = 0.0
    control.run_offline(events)
    first = len(control.outbox)
    for key, msg in early:
        control.process(key, codec.encode(msg), codec.encoding_of(type(msg)), rx_time_ns=0)
    control.process(start_key, codec.encode(start), codec.encoding_of(ScenarioMarker), rx_time_ns=0)
    control.run_offline(events[4:])
    assert control.stray_resets == 1 and fixes(control.outbox[first:]) != reference


# --- the codec itself ---------------------------------------------------------------------------------------------


@settings(max_examples=300)
@given(payload=st.binary(max_size=2000), model=st.sampled_from(sorted(MODELS)))
def test_decode_refuses_arbitrary_bytes_with_a_reason(payload: bytes, model: str) -> None:
    try:
        msg = codec.decode(payload, codec.encoding_of(MODELS[model]))
    except codec.DecodeError as exc:
        assert exc.reason and exc.detail is not None
    else:
        assert isinstance(msg, MODELS[model])


@settings(max_examples=200)
@given(data=st.data(), model=st.sampled_from(sorted(MODELS)))
def test_schema_valid_objects_decode_or_are_refused_and_round_trip(data: st.DataObject, model: str) -> None:
    """Whatever the JSON Schema allows either decodes (and then re-encodes to a message equal to it) or is refused
    with a reason (a check the JSON Schema cannot express, e.g. a covariance that is not positive semi-definite)."""
    obj = data.draw(message_dicts(model))
    payload = _packb(obj)
    try:
        msg = codec.decode(payload, codec.encoding_of(MODELS[model]))
    except codec.DecodeError as exc:
        assert exc.reason
        return
    again = codec.decode(codec.encode(msg), codec.encoding_of(MODELS[model]))
    assert again == msg
    stamp = msg.header.stamp_ns
    assert 0 <= stamp <= MAX_STAMP_NS and math.isfinite(float(stamp))


def test_oversized_and_overdeep_payloads_are_refused_before_they_cost() -> None:
    enc = codec.encoding_of(MODELS["Depth"])
    wide = msgpack.packb({str(i): i for i in range(codec.MAX_MAP_LEN + 1)})
    deep = b"\x91" * 100_000 + b"\xc0"
    big = b"\x00" * (codec.MAX_PAYLOAD_BYTES + 1)
    for payload, reason in [(wide, "too_large"), (deep, "bad_msgpack"), (big, "payload_too_large")]:
        with pytest.raises(codec.DecodeError) as info:
            codec.decode(payload, enc)
        assert info.value.reason == reason
