"""The lbl_nav service adapter without Zenoh (``Service.run_offline`` / ``process``: the same decode, validate and
dispatch path as over a router): configuration, keys, determinism against the core in-process, the player's end
marker, and every bad-input case of issue 3 / digest §5.4 with its diagnostic reason, the counters and an estimate
that stays sane (compared with a run without the bad message)."""

from __future__ import annotations

import contextlib
import math
import os
from collections import Counter
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError
from stack_support import Raw, counters_add_up, delivered, framed, offline_on_bytes, on_key, raw, without_source_seq

from schemas import BeaconRange, BeaconTable, Depth, Diagnostic, Message, ScenarioMarker, SpeedLog, Truth
from schemas.lbl_nav import LblEvent, LblFix
from services.lbl_nav import service as lbl_service
from services.lbl_nav.config import LblNavConfig
from services.lbl_nav.core import LblNavCore
from services.lbl_nav.service import LblNavService, LblNavSettings, event_key, fix_key, input_key
from services.lbl_nav.simulator import sensor_keys
from services.player.scenario import Scenario, parse_scenario
from services.player.timeline import scenario_events
from shared import codec, keys
from shared.errors import InputRejected
from shared.service import Output

VEHICLE = "lbl1"
NS = 1_000_000_000
FIX = fix_key(VEHICLE)
EVENT = event_key(VEHICLE)
DIAG = keys.diag("lbl_nav", VEHICLE)
SENSOR = sensor_keys(VEHICLE)
RANGE_KEY, LOG_KEY = SENSOR["BeaconRange"], SENSOR["SpeedLog"]
Feed = list[tuple[str, Message]]


# ----------------------------------------------------------------------------------------------- helpers
def scenario(duration_s: float = 140.0, seed: int = 4, **params: Any) -> Scenario:
    """The S2 geometry (launch at t = 97 s, resolved about 2 s later) cut at ``duration_s``."""
    sim = {"platform": VEHICLE, "preset": "s2", **params}
    return parse_scenario(
        {
            "name": "lbl_test",
            "seed": seed,
            "duration_s": duration_s,
            "frame_id": "local_enu",
            "wait_for": [f"lbl_nav/{VEHICLE}"],
            "simulators": [{"kind": "lbl_nav", "id": VEHICLE, "params": sim}],
            "estimators": [{"kind": "lbl_nav", "instance": VEHICLE, "params": {}}],
        }
    )


def make_service(**settings: Any) -> LblNavService:
    """The service with the paper's rule (6) unless ``preset`` is given (the S2 timings below are the paper's)."""
    settings.setdefault("preset", "paper")
    return LblNavService(LblNavSettings(instance=settings.pop("instance", VEHICLE), **settings))


def all_events(sc: Scenario) -> Feed:
    return [(ev.key, ev.msg) for ev in scenario_events(sc)]


def inputs(sc: Scenario) -> Feed:
    """What the service's subscription receives of the scenario, in order."""
    return delivered(make_service(), all_events(sc))


def fixes(outputs: Sequence[Output]) -> list[LblFix]:
    return [o.msg for o in outputs if o.key == FIX and isinstance(o.msg, LblFix)]


def diags(outputs: Sequence[Output]) -> list[Diagnostic]:
    return [o.msg for o in outputs if o.key == DIAG and isinstance(o.msg, Diagnostic)]


def core_outputs(feed: Feed, config: LblNavConfig | None = None) -> list[Message]:
    """The core in-process on the same messages (refusals skipped), flushed at the end."""
    core = LblNavCore(config or LblNavConfig(platform=VEHICLE, validate_outputs=False, preset="paper"))
    out: list[Message] = []
    for _, msg in feed:
        if isinstance(msg, ScenarioMarker):
            continue
        with contextlib.suppress(InputRejected):
            out.extend(core.step(msg))
    return out + core.flush()


def stamped(msg: Message, stamp_ns: int, **update: Any) -> Message:
    """A copy of ``msg`` with another stamp (and fields)."""
    return msg.model_copy(update={"header": msg.header.model_copy(update={"stamp_ns": stamp_ns}), **update})


def feed_bytes(svc: LblNavService, items: Iterable[Raw]) -> list[Output]:
    """Process raw samples exactly as the Zenoh callback path does; returns what was published (an end marker
    still waiting for announced samples that never came is forced at the end, as ``end_wait_s`` would)."""
    return offline_on_bytes(svc, items) + svc.run_offline([])


def assert_fix_sane(f: LblFix) -> None:
    """Covariances finite, symmetric, positive definite (the horizontal block; depth has variance 0)."""
    covs = [np.array(h.estimate.covariance)[:2, :2] for h in f.hypotheses]
    if f.valid:
        assert f.estimate is not None and f.state is not None
        covs += [np.array(f.estimate.covariance)[:2, :2], np.array(f.state.covariance)]
    for c in covs:
        assert np.all(np.isfinite(c)) and np.array_equal(c, c.T)
        assert np.linalg.eigvalsh(c)[0] > 0.0, (f.header.stamp_ns, c)


def error_sigmas(f: LblFix, truth: dict[int, Truth]) -> float:
    """Horizontal error of a valid fix against the truth, in sigmas of its own covariance (Mahalanobis)."""
    assert f.estimate is not None
    t = truth[f.header.stamp_ns]
    e = np.array(f.estimate.mean[:2]) - np.array(t.position_m[:2])
    c = np.array(f.estimate.covariance)[:2, :2]
    return float(math.sqrt(e @ np.linalg.solve(c, e)))


def truths(sc: Scenario) -> dict[int, Truth]:
    return {m.header.stamp_ns: m for k, m in all_events(sc) if k == keys.truth(VEHICLE) and isinstance(m, Truth)}


def at(feed: Feed, t_s: float, model: type[Message] = SpeedLog) -> int:
    """Feed position of the first message of ``model`` stamped ``t_s``."""
    stamp = round(t_s * NS)
    return next(i for i, (_, m) in enumerate(feed) if isinstance(m, model) and m.header.stamp_ns == stamp)


@pytest.fixture(scope="module")
def s2() -> tuple[Scenario, Feed, list[Output]]:
    """The cut S2 scenario, the service's input and its clean offline outputs."""
    sc = scenario()
    feed = framed(sc, inputs(sc))
    return sc, feed, make_service().run_offline(feed)


# ----------------------------------------------------------------------------------------------- configuration
def test_settings_from_the_environment_and_build(monkeypatch: pytest.MonkeyPatch) -> None:
    for k in [k for k in os.environ if k.startswith("FIXSTREAM_")]:
        monkeypatch.delenv(k)
    monkeypatch.setenv("FIXSTREAM_LBL_NAV_INSTANCE", "auv7")
    monkeypatch.setenv("FIXSTREAM_LBL_NAV_DN", "5")
    monkeypatch.setenv("FIXSTREAM_LBL_NAV_N_MAX", "97")
    monkeypatch.setenv("FIXSTREAM_LBL_NAV_SIGMA_DK_RAD", "0")
    monkeypatch.setenv("FIXSTREAM_LBL_NAV_R_MERGE_M", "30")
    monkeypatch.setenv(
        "FIXSTREAM_LBL_NAV_BEACONS",
        '[{"beacon_id": "B1", "x_east_m": 0, "y_north_m": 0, "depth_m": 100},'
        ' {"beacon_id": "B2", "x_east_m": 0, "y_north_m": 1500.5, "depth_m": 100}]',
    )
    svc = lbl_service.build()
    assert svc.instance == "auv7" and svc.vehicle == "auv7"  # the vehicle defaults to the instance name
    assert svc.in_key == "fixstream/sensor/auv7/**" == input_key("auv7")
    assert svc.fix_key == "fixstream/fix/lbl/auv7" and svc.event_key == "fixstream/fix/lbl/auv7/event"
    cfg = svc.core_config
    assert cfg.platform == "auv7" and cfg.dN == 5 and cfg.N_max == 97 and cfg.sigma_dK_rad == 0.0
    assert [b.beacon_id for b in cfg.beacons] == ["B1", "B2"] and cfg.beacons[1].y_north_m == 1500.5
    # every other parameter keeps the digest's default (§5.5); the service skips the output re-validation
    default = LblNavConfig(
        platform="auv7",
        dN=5,
        N_max=97,
        sigma_dK_rad=0.0,
        r_merge_m=30.0,
        beacons=cfg.beacons,
        validate_outputs=False,
    )
    assert cfg == default
    assert (cfg.sigma_delta_m, cfg.sigma_v_m, cfg.sigma_dc_mps, cfg.ratio_threshold) == (5.0, 10.0, 3.0, 1e4)
    assert sorted(svc.core.beacons) == ["B1", "B2"]
    status = svc.status()
    assert status["keys"] == {"in": svc.in_key, "fix": svc.fix_key, "event": svc.event_key}
    assert status["beacons"] == ["B1", "B2"] and status["state"] == "WAITING"

    monkeypatch.setenv("FIXSTREAM_LBL_NAV_VEHICLE", "sub-2")
    assert lbl_service.build().in_key == "fixstream/sensor/sub-2/**"
    monkeypatch.setenv("FIXSTREAM_LBL_NAV_VEHICLE", "a/b")
    with pytest.raises(ValidationError, match="vehicle"):
        lbl_service.build()
    monkeypatch.delenv("FIXSTREAM_LBL_NAV_VEHICLE")
    monkeypatch.setenv("FIXSTREAM_LBL_NAV_DN", "0")
    with pytest.raises(ValidationError, match="dN"):
        lbl_service.build()


# ----------------------------------------------------------------------------------------------- determinism
def test_offline_service_equals_the_core_in_process(s2: tuple[Scenario, Feed, list[Output]]) -> None:
    sc, feed, out = s2
    assert {k for k, _ in feed[1:-1]} == set(SENSOR.values())  # truth is not subscribed
    fx = fixes(out)
    assert len(fx) == 141  # one per epoch 0 ... 140 s, the last one at the end marker
    assert {o.key for o in out} == {FIX, EVENT}  # nothing refused, no event worth a diagnostic
    assert [f.header.seq for f in fx] == list(range(141)) and {f.header.source for f in fx} == {"lbl_nav/lbl1"}
    produced = [o.msg for o in out]
    assert without_source_seq(produced) == without_source_seq(core_outputs(feed))
    statuses = [f.status for f in fx]
    assert statuses[:97] == ["BUFFERING"] * 97 and statuses[97] == "LAUNCH"
    k = statuses.index("RESOLVED")  # a few epochs after launch with the buffered data (S2.a: median 2 s)
    assert 98 <= k <= 103 and set(statuses[98:k]) <= {"AMBIGUOUS"} and set(statuses[k + 1 :]) == {"TRACKING"}
    assert [e.kind for e in on_key(out, EVENT)] == ["launch", "decision"]  # type: ignore[attr-defined]
    truth = truths(sc)
    for f in fx:
        assert_fix_sane(f)
        assert f.valid == (f.status in ("RESOLVED", "TRACKING"))
        if f.valid:
            assert error_sigmas(f, truth) < 4.5, f.header.stamp_ns
    svc = make_service()
    svc.run_offline(feed)
    counters_add_up(svc)
    assert svc.counters.rejected == 0 and svc.status()["events"] == {"launch": 1, "decision": 1}


def test_outputs_built_without_validation_equal_the_validated_ones(s2: tuple[Scenario, Feed, list[Output]]) -> None:
    """The service skips the output re-validation (validate_outputs False, for speed): the messages are equal to the
    validated ones, field for field, and survive the wire (encode, strict decode)."""
    _, feed, out = s2
    validated = core_outputs(feed, LblNavConfig(platform=VEHICLE, validate_outputs=True, preset="paper"))
    assert without_source_seq(o.msg for o in out) == without_source_seq(validated)
    for o in out[95:105]:
        assert codec.decode(codec.encode(o.msg), codec.encoding_of(type(o.msg))) == o.msg
        assert o.msg.model_fields_set == type(o.msg).model_validate(o.msg.model_dump()).model_fields_set


def test_end_marker_flushes_and_starts_a_fresh_core(s2: tuple[Scenario, Feed, list[Output]]) -> None:
    _, feed, first = s2
    svc = make_service()
    one = svc.run_offline(feed)
    two = svc.run_offline(feed)  # the same scenario again: stamps from 0, accepted by the fresh core
    assert svc.sessions == 3 and svc.counters.rejected == 0
    assert without_source_seq(o.msg for o in one) == without_source_seq(o.msg for o in two)
    assert fixes(one)[-1].header.stamp_ns == 140 * NS  # the last epoch closed by the end marker (flush)

    # the end marker overtakes the last samples (another key): the flush waits for them
    svc = make_service()
    body, end = feed[:-1], feed[-1]
    early = svc.run_offline([*body[:-4], end, *body[-4:]])
    assert svc.status()["scenario"] == {"end_pending": False, "ends": {"complete": 1}, "stray_resets": 0}
    assert svc.sessions == 2
    assert [o.msg for o in early] == [o.msg for o in first]

    # without the reset a replay is refused sample by sample (stamps going back) and adds no fix
    svc = make_service(reset_on_scenario_end=False)
    svc.run_offline(feed)
    again = svc.run_offline(feed)
    assert fixes(again) == [] and svc.counters.rejected > 0
    assert set(svc.counters.rejected_by_reason) <= {"stamp_backwards", "late", "duplicate"}
    counters_add_up(svc)


def test_other_types_on_the_vehicle_keys_are_ignored_and_a_beacon_table_replaces_the_configured_one() -> None:
    sc = scenario(duration_s=110.0)
    feed = inputs(sc)
    table = feed[0][1]
    assert isinstance(table, BeaconTable)
    # configured with the table, fed without it: the same outputs; a Truth on a sensor key is ignored
    configured = make_service(beacons=table.beacons)
    stray = (f"{keys.ROOT}/sensor/{VEHICLE}/gps/0", Truth(header=table.header, platform=VEHICLE, position_m=[0, 0, 0]))
    out = configured.run_offline([stray, *feed[1:]])
    assert configured.status()["counters"]["ignored"] == 1 and configured.counters.rejected == 0
    assert [o.msg for o in out] == [o.msg for o in make_service().run_offline(feed)]
    # a vehicle other than the instance name
    other = make_service(instance="lbl-a", vehicle=VEHICLE)
    assert fixes(other.run_offline(feed)) and other.fix_key == FIX


# ----------------------------------------------------------------------------------------------- bad input
def _with_inserted(
    feed: Feed, insert: dict[int, list[Raw]], drop: Iterable[int] = (), **settings: Any
) -> tuple[list[Output], LblNavService]:
    """Outputs of the feed (as raw samples) with samples inserted after the given positions and some dropped."""
    svc = make_service(**settings)
    gone = set(drop)
    items: list[Raw] = []
    for i, (key, msg) in enumerate(feed):
        if i not in gone:
            items.append(raw(key, msg))
        items.extend(insert.get(i, []))
    return feed_bytes(svc, items), svc


def test_refused_inputs_are_reported_and_leave_the_estimate_untouched(s2: tuple[Scenario, Feed, list[Output]]) -> None:
    """NaN and negative ranges, an unknown beacon, stamps going backwards, a 10 km outlier: each refused with its
    reason on diag, before any state change — the fixes equal those of the run without them."""
    _, feed, clean = s2
    i_pre, i_post = at(feed, 60.0), at(feed, 120.0)
    rng = next(m for _, m in feed[i_post:] if isinstance(m, BeaconRange))
    t_next = rng.header.model_copy(update={"stamp_ns": rng.header.stamp_ns + NS})
    log = next(m for _, m in feed[i_post:] if isinstance(m, SpeedLog))
    cases: list[tuple[Raw, str]] = [
        (raw(RANGE_KEY, BeaconRange.model_construct(**{**dict(rng), "range_m": math.nan})), "non_finite"),
        (raw(RANGE_KEY, BeaconRange.model_construct(**{**dict(rng), "range_m": -850.0})), "out_of_bounds"),
        (raw(RANGE_KEY, BeaconRange.model_construct(**{**dict(rng), "range_m": 0.0})), "out_of_bounds"),
        (raw(RANGE_KEY, rng.model_copy(update={"beacon_id": "B9", "header": t_next})), "unknown_beacon"),
        (raw(RANGE_KEY, rng.model_copy(update={"range_m": 10_000.0, "header": t_next})), "impossible_range"),
        (raw(LOG_KEY, stamped(log, 100 * NS)), "stamp_backwards"),
        (raw(RANGE_KEY, stamped(rng, 110 * NS)), "late"),
        (raw(RANGE_KEY, rng), "duplicate"),  # the same beacon again in its (still open) epoch
        ((LOG_KEY, b"\xc1", codec.encoding_of(SpeedLog)), "bad_msgpack"),
        (raw(SENSOR["Depth"], Depth(header=stamped(log, 119 * NS).header, depth_m=31.0)), "stamp_backwards"),
    ]
    pre = next(m for _, m in feed[i_pre:] if isinstance(m, BeaconRange))
    pre_cases: list[tuple[Raw, str]] = [
        (raw(RANGE_KEY, BeaconRange.model_construct(**{**dict(pre), "range_m": math.inf})), "non_finite"),
        (raw(RANGE_KEY, pre.model_copy(update={"beacon_id": "B7"})), "unknown_beacon"),
        (raw(RANGE_KEY, pre.model_copy(update={"range_m": 10_000.0})), "impossible_range"),
    ]
    i_rng = next(i for i in range(i_post, len(feed)) if feed[i][1] is rng)
    i_pre_rng = next(i for i in range(i_pre, len(feed)) if feed[i][1] is pre)
    out, svc = _with_inserted(feed, {i_rng: [c for c, _ in cases], i_pre_rng: [c for c, _ in pre_cases]})
    expected = Counter(r for _, r in cases + pre_cases)
    assert svc.counters.rejected_by_reason == expected and "internal_error" not in svc.counters.rejected_by_reason
    ds = diags(out)
    assert Counter(d.reason for d in ds) == expected
    assert all(d.level == "warning" and d.key in (RANGE_KEY, LOG_KEY, SENSOR["Depth"]) for d in ds)
    assert next(d for d in ds if d.reason == "unknown_beacon").detail.count("B7") == 1
    counters_add_up(svc)
    # the estimate never saw them: fixes and events exactly those of the clean run
    assert on_key(out, FIX) == on_key(clean, FIX) and on_key(out, EVENT) == on_key(clean, EVENT)
    status = svc.status()
    assert status["counters"]["rejected"] == sum(expected.values()) and svc.sessions == 2


def test_an_outlier_is_gated_for_every_hypothesis_and_reported() -> None:
    """A range 400 m too long after launch passes the physical gate but not the innovation gate (chi2 99.99 % under
    both hypotheses and after the decision): dropped, reported as innovation_gate, and the fixes equal those of the
    run without that range (except the count of rejected ranges)."""
    sc = scenario(duration_s=125.0)
    feed = framed(sc, inputs(sc))
    picks = []
    for t in (98.0, 115.0):  # ambiguous (two hypotheses), then tracking
        picks.append(next(i for i in range(at(feed, t), len(feed)) if isinstance(feed[i][1], BeaconRange)))
    bad = {i: [raw(RANGE_KEY, feed[i][1].model_copy(update={"range_m": feed[i][1].range_m + 400.0}))] for i in picks}  # type: ignore[attr-defined]
    out, svc = _with_inserted(feed, bad, drop=picks)
    ref, _ = _with_inserted(feed, {}, drop=picks)
    assert Counter(d.reason for d in diags(out)) == {"innovation_gate": 2} and svc.counters.rejected == 0
    assert svc.status()["events"]["innovation_gate"] == 2
    gated = [e for e in on_key(out, EVENT) if isinstance(e, LblEvent) and e.kind == "rejected"]
    assert [(e.reason, e.header.stamp_ns) for e in gated] == [
        ("innovation_gate", feed[i][1].header.stamp_ns) for i in picks
    ]
    ref_fixes = fixes(ref)
    got = fixes(out)
    assert len(got) == len(ref_fixes)
    for g, r in zip(got, ref_fixes, strict=True):
        if g.ranges_rejected:
            assert g.header.stamp_ns in {feed[i][1].header.stamp_ns for i in picks} and g.ranges_rejected == 1
            g = g.model_copy(update={"ranges_rejected": 0})
        assert g == r
        assert_fix_sane(g)


def test_a_log_missing_for_30_s_is_reported_and_the_estimate_stays_consistent() -> None:
    """After launch: 30 s without SpeedLog. The core holds the last values with an inflated sigma_w (degraded
    fixes, dr_gap / dr_restored on diag); the covariance stays SPD and grows; the errors stay within their sigmas.
    Before launch the same gap truncates the buffer (buffer_truncated)."""
    sc = scenario(duration_s=170.0, dropouts=[{"stream": "log", "start_s": 110.0, "duration_s": 30.0}])
    feed = framed(sc, inputs(sc))
    assert not any(isinstance(m, SpeedLog) and 110 * NS <= m.header.stamp_ns < 140 * NS for _, m in feed)
    svc = make_service()
    out = svc.run_offline(feed)
    ds = diags(out)
    assert [(d.reason, d.level, d.header.stamp_ns) for d in ds] == [
        ("dr_gap", "warning", 110 * NS),
        ("dr_restored", "info", 140 * NS),
    ]
    counters_add_up(svc)
    assert svc.counters.rejected == 0
    fx = {f.header.stamp_ns: f for f in fixes(out)}
    assert [t // NS for t, f in fx.items() if f.degraded] == list(range(110, 140))
    truth = truths(sc)
    sig = {t: math.sqrt(f.estimate.covariance[0][0] + f.estimate.covariance[1][1]) for t, f in fx.items() if f.valid}  # type: ignore[index]
    assert sig[139 * NS] > 1.3 * sig[109 * NS]  # held log values, sigma_w inflated: the uncertainty grows
    for t, f in fx.items():
        assert_fix_sane(f)
        if f.valid:
            assert error_sigmas(f, truth) < 4.5, t
    assert sig[169 * NS] < sig[139 * NS]  # ranges bring it back down

    # before launch: the buffer is cut at the gap, reported once; the launch uses the epochs after it
    sc = scenario(duration_s=120.0, dropouts=[{"stream": "log", "start_s": 40.0, "duration_s": 30.0}])
    svc = make_service()
    out = svc.run_offline(framed(sc, inputs(sc)))
    reasons = [d.reason for d in diags(out)]
    assert reasons == ["dr_gap", "buffer_truncated", "dr_restored"]
    launch = next(e for e in on_key(out, EVENT) if isinstance(e, LblEvent) and e.kind == "launch")
    # epochs 69 ... 96: epoch 69 keeps its range (going back to it uses the log of (69, 70]), the rest is cut
    assert "N=28" in launch.detail
    assert all(f.valid for f in fixes(out)[-10:])
