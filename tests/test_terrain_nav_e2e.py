"""The terrain_nav service over real processes and a real Zenoh router.

* The issue's end-to-end test: the clean informative-terrain scenario through ``fixstream up router recorder
  player terrain_nav-tan1`` (the repository's compose.yaml, rate 0): the fixes and verdicts read back from the
  MCAP equal, message for message (header included), what the service built as ``build()`` does gives from
  ``run_offline`` on the same scenario events, and the core in-process on the same seed.
* Bad input over a real router: each case of the issue on the wire; the service reports it, stays alive, its
  status counters add up, and the outputs equal its offline twin fed the same bytes.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import pytest
from conftest import REPO, wait_until
from stack_support import (
    as_composed,
    framed,
    live_service,
    offline_on_bytes,
    on_key,
    player_waited_for,
    raw,
    recorded_by_topic,
    run_up,
    with_end_marker,
)
from test_terrain_nav_service import (
    FIX_KEY,
    INS_KEY,
    MAP,
    RA_KEY,
    VERDICT_KEY,
    assert_fix_sane,
    core_outputs,
    inputs_of,
    scenario_feed,
    terrain_scenario,
    truth_of,
    without_seq,
)

from schemas import Diagnostic, InsSample, RadioAltimeter
from schemas.terrain_nav import TerrainFix, TerrainVerdict
from services.player.scenario import load_scenario
from services.player.timeline import scenario_events
from services.terrain_nav import service as terrain_service
from services.terrain_nav.service import TerrainNavService, TerrainNavSettings
from shared import codec, keys

pytestmark = pytest.mark.e2e

SERVICE = "terrain_nav-tan1"


def test_stack_gives_the_offline_and_in_process_fixes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    scenario_path = REPO / "scenarios" / "terrain_nav_informative.yaml"
    log, recordings = run_up(tmp_path, scenario_path, [SERVICE], timeout_s=120)
    assert player_waited_for(log, "fixstream/alive/terrain_nav/tan1")
    got = recorded_by_topic(recordings)

    svc = as_composed(monkeypatch, SERVICE, terrain_service.build, scenario_path)
    scenario = load_scenario(scenario_path)
    feed = framed(scenario, scenario_feed(svc, scenario))
    offline = svc.run_offline(feed)

    fixes, verdicts = got.get(FIX_KEY, []), got.get(VERDICT_KEY, [])
    assert fixes == on_key(offline, FIX_KEY)  # message for message, headers included
    assert verdicts == on_key(offline, VERDICT_KEY)
    assert "fixstream/diag/terrain_nav/tan1" not in got  # nothing was refused
    # the same fixes as the core in-process on the same seed
    core = core_outputs(feed[1:-1])
    assert without_seq(fixes) == without_seq(m for m in core if isinstance(m, TerrainFix))
    assert without_seq(verdicts[:-1]) == without_seq(m for m in core if isinstance(m, TerrainVerdict))
    # the recorded truth scores them: a clean informative flight, every fix within a cell
    truth = truth_of((keys.truth("tan1"), m) for m in got[keys.truth("tan1")])
    assert len(fixes) >= 15
    for f in fixes:
        assert isinstance(f, TerrainFix)
        assert_fix_sane(f, truth)


def test_bad_input_over_a_real_router(router: str) -> None:
    sc = terrain_scenario("informative")
    events = [(ev.key, ev.msg) for ev in scenario_events(sc) if ev.stamp_ns <= 40 * 10**9]
    settings = {"instance": "bad1", "vehicle": "tan1", "map_path": str(MAP)}
    twin = TerrainNavService(TerrainNavSettings(**settings))  # type: ignore[arg-type]
    feed = inputs_of(twin, events)
    items: list[tuple[str, bytes, str]] = []
    expected: Counter[str] = Counter()
    for k, (key, msg) in enumerate(feed):
        t = msg.header.stamp_ns
        if key == INS_KEY and 35.0e9 <= t < 35.5e9:
            continue  # an INS gap of 0.5 s (> ins_max_gap_s = 0.2 s)
        if key == INS_KEY and t == 38.0e9:
            assert isinstance(msg, InsSample)
            msg = msg.model_copy(update={"x_m": 1.0e7})  # a position far outside the map
        items.append(raw(key, msg))
        if k == 301:
            items.append((RA_KEY, b"\xc1", codec.encoding_of(RadioAltimeter)))  # not msgpack
            expected["bad_msgpack"] += 1
        elif k == 401:
            header = msg.header.model_copy(update={"stamp_ns": t + 10**7})
            nan = RadioAltimeter.model_construct(header=header, h_agl_m=math.nan, valid=True)
            items.append(raw(RA_KEY, nan))  # NaN height
            expected["non_finite"] += 1
        elif k == 501:
            flag = RadioAltimeter(
                header=msg.header.model_copy(update={"stamp_ns": t + 10**7}), h_agl_m=500.0, valid=False
            )
            items.append(raw(RA_KEY, flag))  # the data-valid flag is false
            expected["ra_invalid"] += 1
        elif k == 601:
            back = RadioAltimeter(header=msg.header.model_copy(update={"stamp_ns": t - 10**9}), h_agl_m=500.0)
            items.append(raw(RA_KEY, back))  # the stamp goes backwards
            expected["stamp_backwards"] += 1
        elif k == 701:
            items.append(raw(RA_KEY, feed[k - 1][1]))  # an INS sample on the radio-altimeter key
            expected["unexpected_type"] += 1
        elif k == 801:
            items.append((RA_KEY, codec.encode(msg), "application/msgpack;fixstream.RadioAltimeter/99"))
            expected["schema_version"] += 1
    items = with_end_marker(sc, items, events[-1][1].header.stamp_ns)  # counting them as the player's does

    # the offline twin on exactly these bytes
    offline = offline_on_bytes(twin, items)
    off_reasons = Counter(o.msg.reason for o in offline if isinstance(o.msg, Diagnostic))
    # the INS gap: one ins_gap report, RA samples that cannot be synchronised; the far position: out_of_zone
    assert off_reasons["ins_gap"] == 1 and off_reasons["unsynchronised"] >= 5 and off_reasons["out_of_zone"] == 1
    expected["unsynchronised"] = off_reasons["unsynchronised"]
    assert twin.counters.rejected_by_reason == expected

    env = {f"FIXSTREAM_TERRAIN_NAV_{k.upper()}": v for k, v in settings.items()}
    diag_key = keys.diag("terrain_nav", "bad1")
    with live_service(router, "terrain_nav", "bad1", [FIX_KEY, VERDICT_KEY], **env) as live:
        live.put_raw(items)

        def resets() -> int:
            return sum(isinstance(v, TerrainVerdict) and v.state == "RESET" for v in live.received[VERDICT_KEY])

        n_diag = sum(o.key == diag_key for o in offline)
        assert wait_until(lambda: resets() == 1 and live.count(diag_key) == n_diag, timeout=60)
        assert live.proc.poll() is None and live.alive(1.0)  # still alive, and its status adds up
        status = live.status()
        c = status["counters"]
        assert c["received"] == len(items) == c["accepted"] + c["rejected"]
        assert c["rejected_by_reason"] == dict(expected)
        assert c["rejected"] == sum(expected.values()) and status["pending"] == 0
        assert status["events"]["ins_gap"] == 1 and status["events"]["out_of_zone"] == 1
    received = live.received

    # the same outputs as the offline twin, and the diagnostics name every case with its key
    assert received[FIX_KEY] == on_key(offline, FIX_KEY)
    assert received[VERDICT_KEY] == on_key(offline, VERDICT_KEY)
    diags = [d for d in received[diag_key] if isinstance(d, Diagnostic)]
    assert Counter(d.reason for d in diags) == off_reasons
    assert all(d.key == RA_KEY for d in diags if d.reason in ("bad_msgpack", "non_finite", "ra_invalid"))
    # good messages after the bad ones still give correct fixes
    truth = truth_of(events)
    fixes = [f for f in received[FIX_KEY] if isinstance(f, TerrainFix)]
    assert any(f.header.stamp_ns > 30e9 for f in fixes)
    for f in fixes:
        assert_fix_sane(f, truth)
