"""The attitude service over real processes and a real Zenoh router (issue 7).

* End to end: the paper's scenario seen by a 9S15 radar (``scenarios/attitude_9s15.yaml``) through
  ``fixstream up router recorder player attitude-r1`` (the repository's compose.yaml, rate 0): the estimates and
  diagnostics read back from the MCAP equal, message for message (header included), what the service built as
  ``build()`` builds it (from the compose file's environment) gives from ``run_offline`` on the same scenario
  events framed by the player's markers, and the core in-process on the same seed.
* Bad input over a real router: every case of the issue on the wire to a ``fixstream run attitude`` process
  (NaN and inf, missing scans, a target id that changes, plots older than the last, near-zero speed, and the
  transport's own cases); each is reported with its reason, the service stays alive, its status counters add
  up, and its outputs equal those of its offline twin fed the same bytes.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import pytest
from conftest import REPO
from stack_support import (
    as_composed,
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
from test_attitude_service import (
    DIAG_KEY,
    RADAR_KEY,
    SLOW_TARGET,
    all_events,
    assert_estimate_sane,
    build_scenario,
    core_outputs,
    framed,
    inputs_of,
    los_errors,
    make_service,
    plot_of,
    truths_of,
)

from schemas import Diagnostic, RadarPlot, Truth
from schemas.attitude import AttitudeEstimate
from services.attitude import service as attitude_service
from services.player.scenario import load_scenario
from shared import codec

pytestmark = pytest.mark.e2e

SERVICE = "attitude-r1"
SCENARIO = REPO / "scenarios" / "attitude_9s15.yaml"
SITE_ENV = {"FIXSTREAM_ATTITUDE_SITE_ID": "r1"}


def test_stack_gives_the_offline_and_in_process_estimates(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    log, recordings = run_up(tmp_path, SCENARIO, [SERVICE], timeout_s=150)
    assert player_waited_for(log, "fixstream/alive/attitude/r1")
    got = recorded_by_topic(recordings)

    svc = as_composed(monkeypatch, SERVICE, attitude_service.build, SCENARIO)
    scenario = load_scenario(SCENARIO)
    events = all_events(scenario)
    feed = framed(scenario, inputs_of(svc, events))
    offline = svc.run_offline(feed)

    fix_key = "fixstream/fix/attitude/r1/ac1"
    fixes = got.get(fix_key, [])
    assert len(fixes) == 100
    assert fixes == on_key(offline, fix_key)  # message for message, headers included
    assert got.get(DIAG_KEY, []) == on_key(offline, DIAG_KEY)  # the one new_target report
    assert [m.reason for m in got[DIAG_KEY]] == ["new_target"]  # type: ignore[attr-defined]
    assert {k for k in got if k.startswith("fixstream/fix/")} == {fix_key}
    # the same estimates as the core in-process on the same seed
    assert without_source_seq(fixes) == without_source_seq(core_outputs(feed[1:-1]))
    # everything the player published was recorded, and it is the scenario's events
    assert got[RADAR_KEY] == [m for k, m in events if k == RADAR_KEY]
    assert got["fixstream/truth/ac1"] == [m for k, m in events if k == "fixstream/truth/ac1"]
    # scored against the recorded truth: converged, and the errors of one run within 4 sigma
    truth = {m.header.stamp_ns: m for m in got["fixstream/truth/ac1"] if isinstance(m, Truth)}
    valid = [f for f in fixes if isinstance(f, AttitudeEstimate) and f.status == "VALID"]
    assert len(valid) >= 50
    for f in valid:
        assert_estimate_sane(f)
        errs = los_errors(f, truth[f.header.stamp_ns])
        sig = (f.sigma_psi_los_deg, f.sigma_theta_los_deg, f.sigma_gamma_los_deg)
        assert all(abs(e) <= 4.0 * s for e, s in zip(errs.values(), sig, strict=True)), (f.header.stamp_ns, errs, sig)


def test_bad_input_over_a_real_router(router: str) -> None:
    targets = [
        {"id": "a", "plan": "paper", "missed_scans": [30, 31, 50, 51, 52, 53]},  # a short gap, then a long one
        {"id": "b", "plan": "paper", "phase_s": 1.5},  # its id changes at t = 200 s
        {**SLOW_TARGET, "phase_s": 3.0},  # near-zero speed from t = 290 s
    ]
    sc = build_scenario(targets, duration_s=400.0)
    twin = make_service(instance="bad1", site_id="r1")
    feed = inputs_of(twin, all_events(sc))
    a20 = plot_of(feed, "a", 20)
    items: list[tuple[str, bytes, str]] = []
    expected: Counter[str] = Counter()
    for key, msg in feed:
        if isinstance(msg, RadarPlot) and msg.target_id == "b" and msg.header.stamp_ns >= 200e9:
            msg = msg.model_copy(update={"target_id": "b2"})  # the radar renumbered the track
        items.append(raw(key, msg))
        if msg is a20:
            later = msg.header.model_copy(update={"stamp_ns": msg.header.stamp_ns + 10**8})
            items.append(raw(key, RadarPlot.model_construct(**{**dict(msg), "header": later, "range_m": math.nan})))
            items.append(raw(key, RadarPlot.model_construct(**{**dict(msg), "header": later, "el_deg": math.inf})))
            expected["non_finite"] += 2
            items.append(raw(key, plot_of(feed, "a", 12)))  # a plot older than the last one
            expected["out_of_order"] += 1
            items.append(raw(key, msg))  # the same plot again
            expected["duplicate_time"] += 1
            items.append((key, b"\x93\x01\x02\x03", codec.encoding_of(RadarPlot)))  # [1, 2, 3], not an object
            expected["wrong_type"] += 1
            items.append((key, b"\xc1", codec.encoding_of(RadarPlot)))  # not msgpack
            expected["bad_msgpack"] += 1
            items.append(raw(key, Truth(header=later, platform="a", position_m=[0.0, 0.0, 0.0])))
            expected["unexpected_type"] += 1
            items.append(raw(key, msg.model_copy(update={"header": later, "target_id": "a*"})))
            expected["invalid_target_id"] += 1
            items.append(raw(key, msg.model_copy(update={"header": later, "range_m": msg.range_m + 8000.0})))
            expected["innovation_gate"] += 1
    items = with_end_marker(sc, items, feed[-1][1].header.stamp_ns)  # counting them as the player's does

    # the offline twin on exactly these bytes
    offline = offline_on_bytes(twin, items)
    off_diags = [o.msg for o in offline if isinstance(o.msg, Diagnostic)]
    off_reasons = Counter(d.reason for d in off_diags)
    assert twin.counters.rejected_by_reason == expected
    events = {r: n for r, n in off_reasons.items() if r not in expected}
    assert events.pop("pitch_undefined", 0) <= 1  # slow, once its speed estimate falls below v_min (10 m/s)
    assert events == {
        "new_target": 4,  # a, b, slow, and b2 (the changed id)
        "scans_missed": 1,
        "gap_reset": 1,
        "target_evicted": 1,  # b, 60 s after its last plot
        "heading_undefined": 1,  # slow
        "seq_gap": 1,  # the missed scans are missing from the player's seq on the plot key
    }
    assert twin.sessions == 2  # the end marker started a fresh core

    # on the wire: the same outputs as the offline twin, message for message, its status adding up
    listen = ["fixstream/fix/attitude/r1/*"]
    run = live_run_equals_offline(router, "attitude", "bad1", listen, items, offline, expected, **SITE_ENV)
    status, received = run.status, run.received
    base = {"seq_gap"}  # the service base's own reports (status["seq"]), not the service's events
    assert status["events"] == dict(Counter(d.reason for d in off_diags if d.reason not in set(expected) | base))
    assert status["seq"]["seq_gap"] == 1
    assert status["site_id"] == "r1" and status["targets"] == 0 and not status["scenario"]["end_pending"]
    # every case named with its key
    assert all(d.key == RADAR_KEY for d in run.diags)
    # good plots after the bad ones still give sane estimates; the gated outlier did not move the state
    a_fixes = [m for m in received["fixstream/fix/attitude/r1/a"] if isinstance(m, AttitudeEstimate)]
    after = next(f for f in a_fixes if f.header.stamp_ns == round(100e9))  # the plot after the bad ones
    assert after.flags[:3] == ["OUT_OF_ORDER_DROPPED", "DUPLICATE_DROPPED", "GATE_REJECTED"]
    for f in received["fixstream/fix/attitude/r1/a"] + received["fixstream/fix/attitude/r1/slow"]:
        assert isinstance(f, AttitudeEstimate)
        assert_estimate_sane(f)
    truth = truths_of(all_events(sc), "a")
    for f in a_fixes:
        if f.status == "VALID":
            errs = los_errors(f, truth[f.header.stamp_ns])
            sig = (f.sigma_psi_los_deg, f.sigma_theta_los_deg, f.sigma_gamma_los_deg)
            assert all(abs(e) <= 4.0 * s for e, s in zip(errs.values(), sig, strict=True)), f.header.stamp_ns
