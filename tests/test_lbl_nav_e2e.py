"""The lbl_nav service over real processes and a real Zenoh router (issue 3).

* End to end: the digest's S2 scenario (``scenarios/lbl_nav_s2.yaml``) through ``fixstream up router recorder
  player lbl_nav-lbl1`` (the repository's compose.yaml, rate 0): the fixes, events and diagnostics read back from
  the MCAP equal, message for message (header included), what the service built as ``build()`` builds it (from the
  compose file's environment) gives from ``run_offline`` on the same scenario events framed by the player's
  markers, and the core in-process on the same seed; the Monte-Carlo metrics of the recording equal ``fixstream
  mc``'s ``run_core`` on the same run.
* Bad input over a real router: every case of the issue on the wire to a ``fixstream run lbl_nav`` process (NaN
  and negative ranges, an unknown beacon, stamps going backwards, a 10 km outlier, a gated outlier, the log
  missing for 30 s, and the transport's own cases); each is reported with its reason, the service stays alive,
  its status counters add up, and its outputs equal those of its offline twin fed the same bytes.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import pytest
from conftest import REPO
from stack_support import (
    as_composed,
    delivered,
    framed,
    live_run_equals_offline,
    offline_on_bytes,
    on_key,
    player_waited_for,
    raw,
    recorded_by_topic,
    run_up,
    with_end_marker,
    without_source_seq,
)
from test_lbl_nav_service import (
    EVENT,
    FIX,
    LOG_KEY,
    RANGE_KEY,
    SENSOR,
    all_events,
    assert_fix_sane,
    at,
    core_outputs,
    diags,
    error_sigmas,
    make_service,
    scenario,
    truths,
)

from schemas import BeaconRange, Diagnostic, SpeedLog, Truth
from schemas.lbl_nav import LblEvent, LblFix
from services.lbl_nav import mc
from services.lbl_nav import service as lbl_service
from services.player.scenario import load_scenario
from services.player.simulators import Event
from services.player.timeline import scenario_events
from shared import codec, keys

pytestmark = pytest.mark.e2e

SERVICE = "lbl_nav-lbl1"
SCENARIO = REPO / "scenarios" / "lbl_nav_s2.yaml"
NS = 1_000_000_000


def test_stack_gives_the_offline_and_in_process_fixes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    log, recordings = run_up(tmp_path, SCENARIO, [SERVICE], timeout_s=150)
    assert player_waited_for(log, "fixstream/alive/lbl_nav/lbl1")
    got = recorded_by_topic(recordings)

    svc = as_composed(monkeypatch, SERVICE, lbl_service.build, SCENARIO)
    sc = load_scenario(SCENARIO)
    events = scenario_events(sc)
    feed = framed(sc, delivered(svc, [(e.key, e.msg) for e in events]))
    offline = svc.run_offline(feed)

    fixes = got.get(FIX, [])
    assert len(fixes) == 188  # one per epoch 0 ... 187 s, the last one at the end marker
    assert fixes == on_key(offline, FIX)  # message for message, headers included
    assert got.get(EVENT, []) == on_key(offline, EVENT)
    assert [e.kind for e in got[EVENT]] == ["launch", "decision"]  # type: ignore[attr-defined]
    assert keys.diag("lbl_nav", "lbl1") not in got and not diags(offline)  # nothing refused
    assert {k for k in got if k.startswith("fixstream/fix/")} == {FIX, EVENT}
    # the same outputs as the core in-process on the same seed
    core = core_outputs(feed, svc.core_config)  # the composed service's configuration (the default preset)
    assert without_source_seq(m for m in core if isinstance(m, LblFix)) == without_source_seq(fixes)
    assert without_source_seq(m for m in core if isinstance(m, LblEvent)) == without_source_seq(got[EVENT])
    # everything the player published was recorded, and it is the scenario's events
    for key in (*SENSOR.values(), keys.truth("lbl1")):
        assert got[key] == [e.msg for e in events if e.key == key], key
    # scored against the recorded truth: resolved within a few epochs of launch, errors within their sigmas
    truth = {m.header.stamp_ns: m for m in got[keys.truth("lbl1")] if isinstance(m, Truth)}
    valid = [f for f in fixes if isinstance(f, LblFix) and f.valid]
    assert len(valid) >= 85
    for f in fixes:
        assert isinstance(f, LblFix)
        assert_fix_sane(f)
    for f in valid:
        assert error_sigmas(f, truth) < 4.5, f.header.stamp_ns
    # the Monte-Carlo metrics of the recording are those of fixstream mc on the same run (the compose service runs
    # the digest's defaults, so the estimator's params are taken with the default configuration)
    outputs = [Event(m.header.stamp_ns, k, m) for k in (FIX, EVENT) for m in got[k]]
    outputs.sort(key=lambda e: (e.stamp_ns, e.key == FIX))
    params = {"grid_step_s": 1.0}
    from_recording = mc.run_metrics(outputs, events, params, sc)
    expected = mc.run_core(events, params, sc)
    assert from_recording == {k: v for k, v in expected.items() if k not in mc.OFFLINE_ONLY}
    assert from_recording["with"]["resolution_t_s"] <= 6.0 and not from_recording["with"]["wrong"]


def test_bad_input_over_a_real_router(router: str) -> None:
    sc = scenario(duration_s=170.0, dropouts=[{"stream": "log", "start_s": 130.0, "duration_s": 30.0}])
    twin = make_service(instance="bad1", vehicle="lbl1", preset="honest")  # the live service's default preset
    feed = delivered(twin, all_events(sc))
    i_pre, i_post, i_gate = at(feed, 60.0), at(feed, 115.0), at(feed, 120.0)
    pre = next(m for _, m in feed[i_pre:] if isinstance(m, BeaconRange))
    rng = next(m for _, m in feed[i_post:] if isinstance(m, BeaconRange))
    gate = next(m for _, m in feed[i_gate:] if isinstance(m, BeaconRange))
    log = next(m for _, m in feed[i_post:] if isinstance(m, SpeedLog))
    t_next = rng.header.model_copy(update={"stamp_ns": rng.header.stamp_ns + NS})
    back = log.header.model_copy(update={"stamp_ns": log.header.stamp_ns - 5 * NS})
    expected: Counter[str] = Counter()
    items: list[tuple[str, bytes, str]] = []
    for key, msg in feed:
        if msg is gate:  # replaced by a range 400 m too long: taken, then gated under every hypothesis
            items.append(raw(key, msg.model_copy(update={"range_m": msg.range_m + 400.0})))
            continue
        items.append(raw(key, msg))
        if msg is pre:
            items.append(raw(key, BeaconRange.model_construct(**{**dict(pre), "range_m": math.nan})))
            items.append(raw(key, pre.model_copy(update={"beacon_id": "B9"})))
            expected.update(["non_finite", "unknown_beacon"])
        if msg is rng:
            items.append(raw(key, BeaconRange.model_construct(**{**dict(rng), "range_m": -850.0})))
            items.append(raw(key, rng.model_copy(update={"range_m": 10_000.0, "header": t_next})))
            items.append(raw(key, rng.model_copy(update={"beacon_id": "B3", "header": t_next})))
            items.append(raw(LOG_KEY, log.model_copy(update={"header": back})))
            items.append(raw(key, rng.model_copy(update={"header": back})))
            items.append((key, b"\x93\x01\x02\x03", codec.encoding_of(BeaconRange)))  # [1, 2, 3], not an object
            items.append((key, b"\xc1", codec.encoding_of(BeaconRange)))  # not msgpack
            items.append(raw(key, Truth(header=t_next, platform="lbl1", position_m=[0.0, 0.0, 0.0])))  # ignored
            expected.update(("out_of_bounds", "impossible_range", "unknown_beacon", "stamp_backwards", "late"))
            expected.update(("wrong_type", "bad_msgpack"))
    items = with_end_marker(sc, items, feed[-1][1].header.stamp_ns)  # counting them as the player's does

    # the offline twin on exactly these bytes
    offline = offline_on_bytes(twin, items)
    off_diags = [o.msg for o in offline if isinstance(o.msg, Diagnostic)]
    assert twin.counters.rejected_by_reason == expected
    events = Counter(d.reason for d in off_diags if d.reason not in expected)
    # seq_gap: the DR samples held back for the gap are missing from the player's seq on their key
    assert events == {"innovation_gate": 1, "dr_gap": 1, "dr_restored": 1, "seq_gap": 1}
    assert twin.sessions == 2 and twin.counters.ignored == 1

    # on the wire: the same outputs as the offline twin, message for message, its status adding up
    env = {"FIXSTREAM_LBL_NAV_VEHICLE": "lbl1"}
    run = live_run_equals_offline(router, "lbl_nav", "bad1", [FIX, EVENT], items, offline, expected, **env)
    status, received = run.status, run.received
    core_events = {k: n for k, n in events.items() if k != "seq_gap"}  # seq gaps are the base's (status["seq"])
    assert status["events"] == {**core_events, "launch": 1, "decision": 1}
    assert status["counters"]["ignored"] == 1
    assert status["seq"]["seq_gap"] == 1
    assert status["vehicle"] == "lbl1" and status["state"] == "WAITING" and not status["scenario"]["end_pending"]
    # every case named with its key
    assert all(d.key in (RANGE_KEY, LOG_KEY, SENSOR["Heading"], SENSOR["Depth"]) for d in run.diags)
    # the estimate: covariances SPD at every epoch, errors within their sigmas, the log gap flagged
    truth = truths(sc)
    fixes = [m for m in received[FIX] if isinstance(m, LblFix)]
    assert len(fixes) == 171 and [f.header.stamp_ns // NS for f in fixes if f.degraded] == list(range(130, 160))
    gated = next(f for f in fixes if f.header.stamp_ns == gate.header.stamp_ns)
    assert gated.ranges_rejected == 1
    for f in fixes:
        assert_fix_sane(f)
        if f.valid:
            assert error_sigmas(f, truth) < 4.5, f.header.stamp_ns
