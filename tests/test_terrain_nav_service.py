"""The terrain_nav service adapter without Zenoh (``run_offline``: the service's own decode/dispatch path).

Settings from the environment, equality with the core in-process, the reorder buffer, every bad-input case
of the issue (reported with its reason, counters adding up, the estimate not corrupted), sessions and the
GeoTIFF map path. The same cases over a real router are in ``test_terrain_nav_e2e.py``.
"""

from __future__ import annotations

import contextlib
import math
from collections import Counter
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
import zenoh
from stack_support import counters_add_up as stack_counters_add_up
from stack_support import framed, on_key

from schemas import Depth, Diagnostic, Header, InsSample, Message, NavReset, RadioAltimeter, Truth
from schemas.terrain_nav import TerrainFix, TerrainVerdict
from services.player.scenario import Scenario, load_scenario, parse_scenario
from services.player.timeline import scenario_events
from services.terrain_nav import service as svc_module
from services.terrain_nav.config import TerrainNavConfig
from services.terrain_nav.core import TerrainNavigator
from services.terrain_nav.maps import load_npy
from services.terrain_nav.metrics import TruthTrack, fix_errors_cells
from services.terrain_nav.resampler import CellMeasurement
from services.terrain_nav.service import ReorderBuffer, TerrainNavService, TerrainNavSettings
from shared import codec, keys
from shared.service import InputRejected, Output

REPO = Path(__file__).resolve().parent.parent
MAP = REPO / "scenarios" / "maps" / "terrain_nav_informative.npy"
VEHICLE = "tan1"
FIX_KEY = f"fixstream/fix/terrain/{VEHICLE}"
VERDICT_KEY = f"{FIX_KEY}/verdict"
INS_KEY = f"fixstream/sensor/{VEHICLE}/ins/ins0"
RA_KEY = f"fixstream/sensor/{VEHICLE}/radalt/ra0"

Feed = list[tuple[str, Message]]


# --- helpers (also used by test_terrain_nav_e2e.py) -----------------------------------------------------------------


def terrain_scenario(name: str) -> Scenario:
    return load_scenario(REPO / "scenarios" / f"terrain_nav_{name}.yaml")


def variant(name: str, **params: Any) -> Scenario:
    """A shipped terrain_nav scenario with some simulator parameters replaced."""
    doc = yaml.safe_load((REPO / "scenarios" / f"terrain_nav_{name}.yaml").read_text())
    doc["simulators"][0]["params"].update(params)
    return parse_scenario(doc, f"{name} variant")


def make_service(instance: str = VEHICLE, **settings: Any) -> TerrainNavService:
    return TerrainNavService(TerrainNavSettings(instance=instance, map_path=str(MAP), **settings))


def inputs_of(svc: TerrainNavService, events: Iterable[tuple[str, Message]]) -> Feed:
    """The (key, message) pairs the service's subscriptions receive, in order."""
    exprs = [zenoh.KeyExpr(s.key_expr) for s in svc.subscriptions()]
    return [(k, m) for k, m in events if any(e.intersects(zenoh.KeyExpr(k)) for e in exprs)]


def scenario_feed(svc: TerrainNavService, scenario: Scenario, seed: int | None = None) -> Feed:
    return inputs_of(svc, [(ev.key, ev.msg) for ev in scenario_events(scenario, seed)])


def diags(outputs: Sequence[Output], instance: str = VEHICLE) -> list[Diagnostic]:
    return [o.msg for o in outputs if o.key == keys.diag("terrain_nav", instance) and isinstance(o.msg, Diagnostic)]


def core_outputs(feed: Feed, source: str = f"terrain_nav/{VEHICLE}") -> list[Message]:
    """The core in-process on the same messages (refusals skipped), as the service would stamp them."""
    nav = TerrainNavigator(load_npy(MAP), TerrainNavConfig(), source=source)
    out: list[Message] = []
    for _, msg in feed:
        with contextlib.suppress(InputRejected):
            out.extend(nav.step(msg))
    return out


def without_seq(msgs: Iterable[Message]) -> list[Message]:
    return [m.model_copy(update={"header": m.header.model_copy(update={"seq": 0})}) for m in msgs]


def truth_of(events: Iterable[tuple[str, Message]]) -> TruthTrack:
    return TruthTrack([m for k, m in events if k == keys.truth(VEHICLE) and isinstance(m, Truth)], 125.0)


def assert_fix_sane(fix: TerrainFix, truth: TruthTrack, max_cells: float = 1.0) -> None:
    cov = np.array(fix.estimate.covariance)
    assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
    ex, ez = fix_errors_cells(fix, truth)
    assert max(abs(ex), abs(ez)) <= max_cells, (fix.header.stamp_ns, ex, ez)


def counters_add_up(svc: TerrainNavService) -> None:
    stack_counters_add_up(svc)
    assert svc.status()["pending"] == len(svc.buffer)


def _hdr(stamp_ns: int) -> Header:
    return Header(stamp_ns=stamp_ns, frame_id="map")


@pytest.fixture(scope="module")
def informative() -> tuple[Scenario, list[tuple[str, Message]]]:
    sc = terrain_scenario("informative")
    return sc, [(ev.key, ev.msg) for ev in scenario_events(sc)]


@pytest.fixture(scope="module")
def clean_run(informative: tuple[Scenario, list[tuple[str, Message]]]) -> tuple[Feed, list[Output]]:
    sc, events = informative
    svc = make_service()
    feed = framed(sc, inputs_of(svc, events))
    return feed, svc.run_offline(feed)


# --- configuration ---------------------------------------------------------------------------------------------------


def test_settings_come_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FIXSTREAM_TERRAIN_NAV_INSTANCE", "jet7")
    monkeypatch.setenv("FIXSTREAM_TERRAIN_NAV_MAP_PATH", "scenarios/maps/terrain_nav_informative.npy")
    monkeypatch.setenv("FIXSTREAM_TERRAIN_NAV_REORDER_S", "0.25")
    monkeypatch.setenv("FIXSTREAM_TERRAIN_NAV_CORE__N_MIN", "30")
    monkeypatch.setenv("FIXSTREAM_TERRAIN_NAV_CORE__MU_F", "0.7")
    svc = svc_module.build()
    assert svc.source == "terrain_nav/jet7" and svc.vehicle == "jet7"
    assert svc.fix_key == "fixstream/fix/terrain/jet7" and svc.verdict_key == "fixstream/fix/terrain/jet7/verdict"
    assert [s.key_expr for s in svc.subscriptions()] == ["fixstream/sensor/jet7/**"]  # one: keeps the order
    assert svc.buffer.horizon_ns == 250_000_000
    assert svc.nav.N_min == 30 and svc.nav.cfg.mu_F == 0.7 and svc.nav.cfg.N_max == 64
    assert svc.status()["config"]["core"]["N_min"] == 30
    # every other parameter keeps the digest's default
    rest = svc.config.core.model_dump(exclude={"N_min", "mu_F"})
    assert rest == TerrainNavConfig().model_dump(exclude={"N_min", "mu_F"})


def test_settings_refuse_bad_values() -> None:
    with pytest.raises(ValueError, match="map_path"):
        TerrainNavSettings(instance="x")  # type: ignore[call-arg]
    with pytest.raises(ValueError, match="invalid key chunk"):
        TerrainNavSettings(instance="x", map_path=str(MAP), radalt_sensor="ra/0")
    with pytest.raises(ValueError, match="N_max must exceed N_min"):
        TerrainNavSettings(instance="x", map_path=str(MAP), core={"N_min": 64, "N_max": 64})
    with pytest.raises(FileNotFoundError, match=r"nowhere\.npy"):
        TerrainNavService(TerrainNavSettings(instance="x", map_path="nowhere.npy"))


def test_vehicle_may_differ_from_the_instance_and_other_sensors_are_ignored(
    clean_run: tuple[Feed, list[Output]],
) -> None:
    feed, clean_out = clean_run
    svc = make_service(instance="second", vehicle="tan1", radalt_sensor="ra0")
    assert svc.fix_key == FIX_KEY and svc.source == "terrain_nav/second"
    t = feed[5][1].header.stamp_ns
    others: Feed = [
        ("fixstream/sensor/tan1/radalt/ra9", RadioAltimeter(header=_hdr(t + 1), h_agl_m=1.0)),  # another altimeter
        ("fixstream/sensor/tan1/dvl/dvl0", Depth(header=_hdr(t + 2), depth_m=1.0)),  # another kind of sensor
    ]
    out = svc.run_offline([*feed[:6], *others, *feed[6:]])
    assert svc.counters.ignored == 2 and not diags(out, "second")
    a, b = on_key(out, FIX_KEY), on_key(clean_out, FIX_KEY)
    skip: Any = {"header": True, "verdict": {"header"}}
    assert [m.model_dump(exclude=skip) for m in a] == [m.model_dump(exclude=skip) for m in b] and len(a) >= 15
    assert [m.header.stamp_ns for m in a] == [m.header.stamp_ns for m in b]


# --- determinism: the service is the core -----------------------------------------------------------------------------


def test_offline_service_gives_the_core_outputs(
    informative: tuple[Scenario, list[tuple[str, Message]]], clean_run: tuple[Feed, list[Output]]
) -> None:
    _, events = informative
    feed, out = clean_run
    fixes, verdicts = on_key(out, FIX_KEY), on_key(out, VERDICT_KEY)
    core = core_outputs(feed)
    assert without_seq(verdicts[:-1]) == without_seq(m for m in core if isinstance(m, TerrainVerdict))
    assert without_seq(fixes) == without_seq(m for m in core if isinstance(m, TerrainFix))
    assert [m.header.seq for m in fixes] == list(range(len(fixes)))
    assert isinstance(verdicts[-1], TerrainVerdict) and verdicts[-1].state == "RESET"  # the scenario's end
    # a clean informative flight: fixes from ~17 s, all within a cell (digest AT-3 on one flight)
    truth = truth_of(events)
    assert len(fixes) >= 15
    for f in fixes:
        assert isinstance(f, TerrainFix)
        assert_fix_sane(f, truth)
    assert not diags(out)


def test_reorder_buffer_releases_in_stamp_order() -> None:
    buf = ReorderBuffer(100)
    msg = Depth(header=_hdr(0), depth_m=1.0)
    assert buf.push(1000, "b", msg, rank=2) and buf.pop_ready() == []
    assert buf.push(950, "a", msg) and buf.push(1000, "c", msg, rank=2) and buf.push(1000, "ins", msg, rank=0)
    assert buf.push(1100, "d", msg)
    # released up to 1100 - 100; equal stamps by rank, then in arrival order
    assert [k for k, _ in buf.pop_ready()] == ["a", "ins", "b", "c"]
    assert not buf.push(990, "late", msg)  # behind what was released: still queued, flagged late
    assert [k for k, _ in buf.drain()] == ["late", "d"] and len(buf) == 0


def _arrival(feed: Feed, delay_ns: dict[str, int]) -> Feed:
    """The order in which messages arrive when each key is delayed by its own latency (stable per key)."""
    order = sorted(range(len(feed)), key=lambda i: (feed[i][1].header.stamp_ns + delay_ns.get(feed[i][0], 0), i))
    return [feed[i] for i in order]


def test_interleaved_keys_give_the_in_order_outputs(clean_run: tuple[Feed, list[Output]]) -> None:
    feed, out = clean_run
    body = feed[1:-1]
    # the INS arrives 90 ms late, so radio-altimeter samples overtake it
    skewed = [feed[0], *_arrival(body, {INS_KEY: 90_000_000}), feed[-1]]
    assert skewed != feed
    got = make_service().run_offline(skewed)
    assert on_key(got, VERDICT_KEY) == on_key(out, VERDICT_KEY)
    assert on_key(got, FIX_KEY) == on_key(out, FIX_KEY)


def test_reorder_buffer_puts_a_late_reset_back_in_its_place(clean_run: tuple[Feed, list[Output]]) -> None:
    feed, _ = clean_run
    body = feed[1:-1]
    t_reset = body[1200][1].header.stamp_ns + 12_500_000  # between two ticks, ~30 s into the flight
    reset_key = f"fixstream/sensor/{VEHICLE}/reset/ops"
    reset = NavReset(header=_hdr(t_reset), reason="INS reset by the crew")
    in_order = sorted([*body, (reset_key, reset)], key=lambda km: km[1].header.stamp_ns)
    late = _arrival([*body, (reset_key, reset)], {reset_key: 60_000_000})  # the reset arrives 60 ms late
    expected = make_service().run_offline([feed[0], *in_order, feed[-1]])
    got = make_service().run_offline([feed[0], *late, feed[-1]])
    no_buffer = make_service(reorder_s=0.0).run_offline([feed[0], *late, feed[-1]])
    resets = [v for v in on_key(expected, VERDICT_KEY) if isinstance(v, TerrainVerdict) and v.state == "RESET"]
    assert resets[0].detail == "INS reset by the crew" and resets[0].header.stamp_ns == t_reset
    assert on_key(got, VERDICT_KEY) == on_key(expected, VERDICT_KEY)
    assert on_key(got, FIX_KEY) == on_key(expected, FIX_KEY)
    assert on_key(no_buffer, VERDICT_KEY) != on_key(expected, VERDICT_KEY)  # the buffer is what restored it


# --- bad input: each case of the issue --------------------------------------------------------------------------------


def test_bad_inputs_are_reported_and_do_not_touch_the_estimate(clean_run: tuple[Feed, list[Output]]) -> None:
    feed, clean_out = clean_run
    body = feed[1:-1]
    bad: list[tuple[int, str, Message, str]] = []  # (insert after body index, key, message, expected reason)
    assert all(k == RA_KEY for k, _ in body[1::2])  # per tick: INS (even index), then RA (odd index)

    def after(i: int, key: str, msg: Message, reason: str) -> None:
        bad.append((i, key, msg, reason))

    def t(i: int, offset_ms: float) -> int:
        return body[i][1].header.stamp_ns + round(offset_ms * 1e6)

    # NaN heights (refused by the codec: the payload does not validate)
    after(
        301, RA_KEY, RadioAltimeter.model_construct(header=_hdr(t(301, 10)), h_agl_m=math.nan, valid=True), "non_finite"
    )
    nan_ins = InsSample.model_construct(
        header=_hdr(t(500, 10)), x_m=1e4, z_m=9e3, h_m=math.nan, vx_mps=None, vz_mps=None, vh_mps=None, valid=True
    )
    after(500, INS_KEY, nan_ins, "non_finite")
    # flag-false samples (the paper discards them before the algorithm)
    after(701, RA_KEY, RadioAltimeter(header=_hdr(t(701, 10)), h_agl_m=450.0, valid=False), "ra_invalid")
    after(900, INS_KEY, InsSample(header=_hdr(t(900, 10)), x_m=1e4, z_m=9e3, h_m=900.0, valid=False), "ins_invalid")
    # stamps going backwards on a key, and a repeated stamp
    after(1101, RA_KEY, RadioAltimeter(header=_hdr(t(1101, -500)), h_agl_m=450.0), "stamp_backwards")
    after(1301, INS_KEY, InsSample(header=_hdr(t(1301, -1000)), x_m=1e4, z_m=9e3, h_m=900.0), "stamp_backwards")
    dup = body[1501]
    assert dup[0] == RA_KEY
    after(1501, RA_KEY, dup[1].model_copy(update={"h_agl_m": 999.0}), "stamp_not_increasing")
    # a message of the wrong type on a key
    after(1701, RA_KEY, Depth(header=_hdr(t(1701, 10)), depth_m=3.0), "unexpected_type")

    dirty = list(body)
    for i, key, msg, _ in sorted(bad, key=lambda b: -b[0]):
        dirty.insert(i + 1, (key, msg))

    svc = make_service()
    out = svc.run_offline([feed[0], *dirty, feed[-1]])
    # every bad message reported once, with its reason and key, in arrival order
    ds = diags(out)
    assert [(d.reason, d.key) for d in ds] == [(r, k) for _, k, _, r in sorted(bad, key=lambda b: b[0])]
    assert ds[-1].counts == dict(Counter(r for *_, r in bad))
    # counters add up: everything received was either accepted or rejected
    counters_add_up(svc)
    assert svc.counters.rejected == len(bad) and svc.counters.received == len(feed) + len(bad)
    # and the estimate is exactly the clean one: no verdict or fix changed
    assert on_key(out, VERDICT_KEY) == on_key(clean_out, VERDICT_KEY)
    assert on_key(out, FIX_KEY) == on_key(clean_out, FIX_KEY)


def test_ins_gap_over_the_limit_is_reported_and_forms_no_measurement() -> None:
    sc = variant("informative", failures=[{"kind": "ins_gap", "onset_s": 30.0, "duration_s": 1.0}])
    events = [(ev.key, ev.msg) for ev in scenario_events(sc)]
    svc = make_service()
    measurements: list[CellMeasurement] = []
    push = svc.nav.search.push_measurement

    def record(m: CellMeasurement) -> list[Any]:
        measurements.append(m)
        return push(m)

    svc.nav.search.push_measurement = record  # type: ignore[attr-defined]
    feed = framed(sc, inputs_of(svc, events))
    out = svc.run_offline(feed)
    gap_start, gap_end = 30.0, 31.0  # no INS sample in [30, 31) s: the limit is ins_max_gap_s = 0.2 s
    verdicts = [v for v in on_key(out, VERDICT_KEY) if isinstance(v, TerrainVerdict)]
    gaps = [v for v in verdicts if v.state == "GAP"]
    assert len(gaps) == 1 and gaps[0].header.stamp_ns == round(gap_end * 1e9)
    assert "4 queued RA samples dropped" in gaps[0].detail
    reasons = Counter(d.reason for d in diags(out))
    # RA samples more than 0.2 s after the last INS sample are refused (16), the 4 queued ones dropped
    assert reasons == Counter({"unsynchronised": 16, "ins_gap": 1})
    counters_add_up(svc)
    # no cell measurement holds a sample from the gap; the first one after it is not accumulated
    assert all(m.t_last < gap_start or m.t_first >= gap_end for m in measurements)
    first_after = next(m for m in measurements if m.t_first >= gap_end)
    assert first_after.exclude
    # fixes before and after the gap stay correct
    truth = truth_of(events)
    fixes = [f for f in on_key(out, FIX_KEY) if isinstance(f, TerrainFix)]
    assert any(f.header.stamp_ns > gap_end * 1e9 for f in fixes)
    for f in fixes:
        assert_fix_sane(f, truth)


def test_position_outside_the_map_is_reported_and_yields_no_fix() -> None:
    sc = terrain_scenario("out_of_zone")
    events = [(ev.key, ev.msg) for ev in scenario_events(sc)]
    svc = make_service()
    out = svc.run_offline(framed(sc, inputs_of(svc, events)))
    verdicts = [v for v in on_key(out, VERDICT_KEY) if isinstance(v, TerrainVerdict)][:-1]  # without RESET
    ooz = [v for v in verdicts if v.state == "OUT_OF_ZONE"]
    evals = [v for v in verdicts if v.state != "OUT_OF_ZONE"]
    # the zone is where the 51 x 51 patch fits: INS cells 25 .. 174 of the 200-cell map
    ins = [m for k, m in events if k == INS_KEY and isinstance(m, InsSample)]
    inside = [m.header.stamp_ns for m in ins if 25 <= m.x_m // 125.0 < 175]
    t_in, t_out = min(inside), max(inside)
    before = [v for v in ooz if v.header.stamp_ns < t_in]
    after = [v for v in ooz if v.header.stamp_ns > t_out]
    assert len(before) >= 5 and len(after) >= 5 and len(before) + len(after) == len(ooz)
    stamps = np.array([v.header.stamp_ns for v in ooz]) * 1e-9
    assert np.all(np.diff(stamps[: len(before)]) >= 1.0 - 1e-9)  # at most one per second
    assert all(t_in <= v.header.stamp_ns <= t_out for v in evals)  # no evaluation outside
    ds = [d for d in diags(out) if d.reason == "out_of_zone"]
    assert len(ds) == len(ooz) and ds[-1].count == len(ooz) and svc.events["out_of_zone"] == len(ooz)
    assert evals[0].n_measurements == 4 and evals[0].n_valid == 3  # post-gap handling on entry
    truth = truth_of(events)
    fixes = [f for f in on_key(out, FIX_KEY) if isinstance(f, TerrainFix)]
    assert len(fixes) >= 20
    for f in fixes:
        assert t_in <= f.header.stamp_ns <= t_out
        assert_fix_sane(f, truth)
    counters_add_up(svc)


# --- sessions, idle flush, maps ---------------------------------------------------------------------------------------


def test_each_scenario_end_starts_a_new_session(clean_run: tuple[Feed, list[Output]]) -> None:
    feed, first = clean_run
    svc = make_service()
    once = svc.run_offline(feed)
    twice = svc.run_offline(feed)  # played again: stamps start from 0 again and are accepted
    assert not diags(twice) and svc.sessions == 3
    assert without_seq(on_key(twice, VERDICT_KEY)) == without_seq(on_key(once, VERDICT_KEY))
    assert without_seq(on_key(twice, FIX_KEY)) == without_seq(on_key(first, FIX_KEY))
    assert on_key(twice, FIX_KEY)[0].header.seq == len(on_key(once, FIX_KEY))  # seq keeps counting per key


def test_an_end_marker_that_overtakes_the_data_waits_for_it(clean_run: tuple[Feed, list[Output]]) -> None:
    """The end marker comes on another key (another subscriber thread): it may arrive before the last data."""
    feed, clean_out = clean_run
    early = [*feed[:-40], feed[-1], *feed[-40:-1]]  # the marker overtakes the last 39 messages
    svc = make_service()
    out = svc.run_offline(early)
    assert on_key(out, VERDICT_KEY) == on_key(clean_out, VERDICT_KEY)  # RESET last, after all the data
    assert on_key(out, FIX_KEY) == on_key(clean_out, FIX_KEY)
    assert svc.sessions == 2 and not diags(out)
    assert svc.status()["scenario"] == {"end_pending": False, "ends": {"complete": 1}, "stray_resets": 0}
    # a marker whose messages never all arrive: the run waits, then ends anyway (offline: after the last event;
    # online: end_wait_s after the last sample, at the next start marker or when stopping), counted incomplete
    svc = make_service()
    svc._subs = svc.subscriptions()  # what run_offline does, without its final end of input
    for key, msg in [*feed[:-40], feed[-1]]:
        svc.process(key, codec.encode(msg), codec.encoding_of(type(msg)))
    assert svc.sessions == 1 and len(svc.buffer) > 0 and svc.status()["scenario"]["end_pending"]
    part = svc.run_offline([])
    last = on_key(part, VERDICT_KEY)[-1]
    assert isinstance(last, TerrainVerdict) and last.state == "RESET"
    assert svc.status()["scenario"] == {"end_pending": False, "ends": {"incomplete": 1}, "stray_resets": 0}
    assert len(svc.buffer) == 0 and svc.sessions == 2


def test_idle_flush_releases_the_buffer(clean_run: tuple[Feed, list[Output]]) -> None:
    feed, clean_out = clean_run
    svc = make_service(idle_flush_s=1e-6)
    part = svc.run_offline(feed[1:-1])  # no end marker: the last 0.1 s of data waits in the buffer
    assert len(svc.buffer) > 0 and svc.status()["pending"] == len(svc.buffer)
    flushed = svc.on_idle()
    assert len(svc.buffer) == 0
    got = [o.msg for o in part if o.key == VERDICT_KEY] + [o.msg for o in flushed if o.key == VERDICT_KEY]
    assert without_seq(got) == without_seq(on_key(clean_out, VERDICT_KEY)[:-1])


def test_geotiff_map_is_block_averaged_to_the_cell(tmp_path: Path) -> None:
    import rasterio
    from rasterio.transform import Affine

    ref = load_npy(MAP)
    pixel, k = 25.0, 5
    fine = np.kron(ref.dem, np.ones((k, k)))[::-1, :]  # rows north -> south; x = north, z = east
    south, west = 6_200_000.0, 500_000.0
    path = tmp_path / "zone.tif"
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        height=fine.shape[0],
        width=fine.shape[1],
        count=1,
        dtype="float64",
        crs="EPSG:32633",
        transform=Affine(pixel, 0.0, west, 0.0, -pixel, south + fine.shape[0] * pixel),
    ) as dst:
        dst.write(fine, 1)
    svc = TerrainNavService(TerrainNavSettings(instance="geo", map_path=str(path), map_cell_m=125.0))
    assert svc.ref_map.shape == ref.shape and svc.ref_map.cell_m == 125.0
    assert (svc.ref_map.x0_m, svc.ref_map.z0_m) == (south, west)
    assert np.allclose(svc.ref_map.dem, ref.dem, atol=1e-9)
    assert svc.status_extra()["map"]["zone_cells"] == int(ref.zone_mask(25, 25).sum())
    with pytest.raises(ValueError, match="needs the cell size"):
        TerrainNavService(TerrainNavSettings(instance="geo", map_path=str(path)))
