"""PCL tracker service adapter without Zenoh: the same decode/dispatch path (``Service.process`` /
``run_offline``) as over a router, against the core run in-process.

The bad-input stream of digest 003 §5.6 is built here (:func:`dirty_stream`) and reused by the real-router
test in ``test_pcl_tracker_e2e.py``: the paper's E1 stream with every kind of bad input of the issue
interleaved (NaN fields, r_b below zero or impossible, plots too close to the baseline to convert,
out-of-order, repeated and late scans, time going backwards, a clutter burst beyond the configured limit,
undecodable payloads, wrong type and pair). None of it may change the track: its reports must equal, bit
for bit, those of the clean stream.
"""

from __future__ import annotations

import math
import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
import yaml
from conftest import REPO

from schemas import Diagnostic, Header, ScenarioMarker, Truth
from schemas.pcl_tracker import PclScanReport, PclTrackReport
from schemas.radar import BistaticConfigUpdate, BistaticScan
from services.pcl_tracker import service as service_mod
from services.pcl_tracker.config import PclTrackerConfig
from services.pcl_tracker.core import PclTracker
from services.pcl_tracker.service import PclTrackerService, input_key, output_key
from services.pcl_tracker.settings import PclTrackerParams, PclTrackerSettings, to_config
from services.pcl_tracker.simulation import paper_scenario, simulate
from shared import codec, keys

PAIR = ("rx1", "tx-fm-98.1")
IN_KEY = input_key(*PAIR)
OUT_KEY = output_key(*PAIR)
SCAN_ENC = codec.encoding_of(BistaticScan)
#: a seed whose E1 run has a single track (id 1, created at scan 2, never dropped)
SEED = 3


def make_service(instance: str = "t", **settings: Any) -> PclTrackerService:
    """A service on the paper's configuration (``preset: paper``: the digest's E1 stream), unless told otherwise."""
    settings.setdefault("preset", "paper")
    svc = PclTrackerService(PclTrackerSettings(instance=instance, **settings))
    svc._subs = svc.subscriptions()
    return svc


def clean_scans(seed: int = SEED) -> list[BistaticScan]:
    return simulate(paper_scenario(), np.random.default_rng(seed)).scans


def raw(scan: BistaticScan) -> dict[str, Any]:
    return codec.unpack(codec.encode(scan))  # type: ignore[no-any-return]


def pack(obj: dict[str, Any]) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)  # type: ignore[no-any-return]


def plot_dict(pid: str, rb: float, az_deg: float, el_deg: float, vb: float, **extra: Any) -> dict[str, Any]:
    return {
        "plot_id": pid,
        "azimuth_deg": az_deg,
        "elevation_deg": el_deg,
        "bistatic_range_m": rb,
        "bistatic_velocity_mps": vb,
        "sigma_rb_m": 200.0,
        "sigma_az_deg": 0.5,
        "sigma_el_deg": 0.5,
        "sigma_vb_mps": 5.0,
        **extra,
    }


def with_plots(scan: BistaticScan, extra: list[dict[str, Any]]) -> bytes:
    obj = raw(scan)
    obj["plots"] = obj["plots"] + extra
    return pack(obj)


@dataclass(frozen=True)
class Item:
    """One payload of the dirty stream: what is sent, and what must come of it."""

    payload: bytes
    encoding: str
    reject: str | None = None  # the message is refused with this reason
    events: tuple[str, ...] = ()  # scan-level diagnostics it must raise


def _far_plots(n: int, rng: np.random.Generator) -> list[dict[str, Any]]:
    """Clutter far from the target (r_b 120-190 km): never gated to its track."""
    return [
        plot_dict(
            f"c{i:04d}", rng.uniform(120e3, 190e3), rng.uniform(-180, 180), rng.uniform(0, 30), rng.uniform(-400, 400)
        )
        for i in range(n)
    ]


def dirty_stream(scans: list[BistaticScan]) -> list[Item]:
    """The clean scans in order, with the bad input of the issue's list interleaved (see the module doc)."""
    rng = np.random.default_rng(11)
    by_id = {s.scan_id: s for s in scans}
    items: list[Item] = []

    def good(sid: int) -> None:
        items.append(Item(codec.encode(by_id[sid]), SCAN_ENC))

    truth_z = {s.scan_id: (s.plots[0].bistatic_range_m, s.plots[0].azimuth_deg) for s in scans if s.plots}
    sid = 1
    while sid <= len(scans):
        s = by_id[sid]
        if sid == 5:  # NaN and inf fields: those plots are dropped, the scan is kept
            bad = [
                plot_dict("x_nan_rb", math.nan, 10.0, 5.0, 0.0),
                plot_dict("x_inf_vb", 5000.0, 10.0, 5.0, math.inf),
                plot_dict("x_nan_az", 5000.0, math.nan, 5.0, 0.0),
                plot_dict("x_nan_sigma", 5000.0, -100.0, 5.0, 0.0, sigma_rb_m=math.nan),  # kept, default sigma
            ]
            items.append(Item(with_plots(s, bad), SCAN_ENC, events=("nan", "sigma_defaulted")))
        elif sid == 6:  # an elevation beyond 90 deg and a plot with two range forms
            bad = [
                plot_dict("x_el", 5000.0, 10.0, 95.0, 0.0),
                plot_dict("x_two", 5000.0, 10.0, 5.0, 0.0, range_sum_m=13000.0),
            ]
            items.append(Item(with_plots(s, bad), SCAN_ENC, events=("out_of_range", "missing_quantity")))
        elif sid == 7:  # impossible geometry, the direct-signal zone and the range limit
            bad = [
                plot_dict("x_rb_neg", -5000.0, -120.0, 5.0, 0.0),  # range sum < L: impossible
                plot_dict("x_rb_near", -100.0, -120.0, 3.0, 50.0),  # within 3 sigma: clamped to 0
                plot_dict("x_rb_low", 300.0, -150.0, 2.0, 10.0),  # too close to the baseline to convert
                plot_dict("x_rb_far", 250_000.0, 0.0, 1.0, 0.0),  # beyond rb_max_m
            ]
            events = ("rb_below_baseline", "near_baseline", "low_rb", "out_of_range")
            items.append(Item(with_plots(s, bad), SCAN_ENC, events=events))
        elif sid == 8:  # out of order: 9 before 8 (buffered, then both processed in order)
            items.append(Item(codec.encode(by_id[9]), SCAN_ENC, events=("out_of_order",)))
            good(8)
            sid = 10
            continue
        elif sid == 10:  # repeated scan
            good(10)
            items.append(Item(codec.encode(s), SCAN_ENC, reject="duplicate_scan"))
            sid += 1
            continue
        elif sid == 12:  # a scan older than everything processed that was never seen: late
            good(12)
            late = raw(s)
            late["scan_id"] = 0
            items.append(Item(pack(late), SCAN_ENC, reject="late_scan_dropped"))
            sid += 1
            continue
        elif sid == 14:  # the next scan id with a stamp that goes back in time, then the real one
            back = raw(s)
            back["header"]["stamp_ns"] = by_id[12].header.stamp_ns
            items.append(Item(pack(back), SCAN_ENC, reject="time_not_monotonic"))
            good(14)
            sid += 1
            continue
        elif sid == 16:  # clutter burst beyond max_plots_per_scan (500): association only
            items.append(Item(with_plots(s, _far_plots(600, rng)), SCAN_ENC, events=("clutter_burst",)))
        elif sid == 18:  # undecodable payloads, a wrong type and a wrong pair on the key
            items.append(Item(b"\x93\x01", SCAN_ENC, reject="bad_msgpack"))
            items.append(Item(codec.encode(s), "text/plain", reject="bad_encoding"))
            truth = Truth(header=Header(stamp_ns=s.header.stamp_ns), platform="x", position_m=[0.0, 0.0, 0.0])
            items.append(Item(codec.encode(truth), codec.encoding_of(Truth), reject="unexpected_type"))
            other = raw(s)
            other["illuminator_id"] = "tx-other"
            items.append(Item(pack(other), SCAN_ENC, reject="wrong_pair"))
            neg = raw(s)
            neg["scan_id"] = -4
            items.append(Item(pack(neg), SCAN_ENC, reject="out_of_bounds"))
            good(18)
        elif sid == 22:  # a gross outlier next to the target (v_b 30 sigma off): outside the gate
            rb, az = truth_z[sid]
            outlier = plot_dict("x_outlier", rb, az, s.plots[0].elevation_deg, 150.0 + s.plots[0].bistatic_velocity_mps)
            items.append(Item(with_plots(s, [outlier]), SCAN_ENC))
        else:
            good(sid)
        sid += 1
    return items


def run_items(svc: PclTrackerService, items: list[Item]) -> tuple[list[PclScanReport], list[Diagnostic]]:
    start = len(svc.outbox)
    for it in items:
        svc.process(IN_KEY, it.payload, it.encoding, rx_time_ns=0)
    out = svc.outbox[start:]
    reports = [o.msg for o in out if o.key == OUT_KEY]
    diags = [o.msg for o in out if o.key == keys.diag("pcl_tracker", svc.instance)]
    assert all(isinstance(r, PclScanReport) for r in reports)
    assert all(isinstance(d, Diagnostic) for d in diags)
    return reports, diags  # type: ignore[return-value]


def track_view(reports: list[PclScanReport]) -> dict[int, list[tuple[Any, ...]]]:
    """Per scan: every track's id, status, state, covariance, bistatic image and association."""
    return {
        r.scan_id: [(t.track_id, t.status, t.estimate, t.bistatic, t.nis, t.hits) for t in r.tracks]
        for r in reports
        if r.trigger == "scan"
    }


def assert_valid_covariances(reports: list[PclScanReport]) -> None:
    for r in reports:
        for t in r.tracks:
            P = np.array(t.estimate.covariance)
            assert np.array_equal(P, P.T)
            assert float(np.linalg.eigvalsh(P).min()) > 0.0


# ------------------------------------------------------------------------------------------------ tests
def test_offline_service_equals_the_core_in_process() -> None:
    scans = clean_scans()
    svc = make_service()
    out = svc.run_offline([(IN_KEY, s) for s in scans])
    reports = [o.msg for o in out if o.key == OUT_KEY]
    core = PclTracker(paper_scenario().tracker_config(preset="paper"))
    expected = [r for s in scans for r in core.step(s)]
    assert len(reports) == len(expected) == 51
    for k, (got, exp) in enumerate(zip(reports, expected, strict=True)):
        assert got.model_dump(exclude={"header"}) == exp.model_dump(exclude={"header"})
        assert got.header.source == "pcl_tracker/t" and got.header.seq == k
        assert got.header.stamp_ns == exp.header.stamp_ns and got.header.frame_id == "pcl_enu"
    assert [o.key for o in out] == [OUT_KEY] * 51  # nothing to diagnose in a clean stream
    assert svc.counters.rejected == 0 and svc.counters.accepted == 51


def test_reports_are_valid_messages() -> None:
    """Reports are built without pydantic validation: they must equal their validated round trip."""
    scans = simulate(paper_scenario(n_scans=12), np.random.default_rng(1)).scans
    core = PclTracker(paper_scenario().tracker_config(preset="paper", confirm_M=2, confirm_N=3))
    for s in scans:
        for rep in core.step(s):
            again = codec.decode(codec.encode(rep), codec.encoding_of(PclScanReport))
            assert again == rep
            assert all(t.model_fields_set == set(PclTrackReport.model_fields) for t in rep.tracks)


def test_bad_input_is_reported_and_never_changes_the_track() -> None:
    scans = clean_scans()
    clean_svc = make_service("clean")
    clean, _ = run_items(clean_svc, [Item(codec.encode(s), SCAN_ENC) for s in scans])
    assert {t.track_id for r in clean for t in r.tracks} == {1}  # the seed's run has one track

    items = dirty_stream(scans)
    svc = make_service("dirty")
    reports, diags = run_items(svc, items)

    # the track is exactly the clean run's, at every scan; covariances stay symmetric positive definite
    assert [r.scan_id for r in reports] == list(range(1, 52))
    assert track_view(reports) == track_view(clean)
    assert_valid_covariances(reports)
    burst = next(r for r in reports if r.scan_id == 16)
    assert "clutter_burst" in burst.flags and burst.n_associated == 1 and burst.n_initiated == 0
    outlier = next(r for r in reports if r.scan_id == 22)
    assert outlier.tracks[0].associated_plot_id != "x_outlier" and outlier.tracks[0].n_plots_in_gate == 1

    # every refused message and every scan-level problem was reported with its reason
    reasons = Counter(d.reason for d in diags)
    expected_rejects = Counter(it.reject for it in items if it.reject)
    for reason, n in expected_rejects.items():
        assert reasons[reason] == n, (reason, reasons)
    for it in items:
        for ev in it.events:
            assert reasons[ev] >= 1, (ev, reasons)
    assert all(d.key == IN_KEY and d.service == "pcl_tracker" and d.instance == "dirty" for d in diags)

    # the counters add up
    c = svc.counters
    assert c.received == len(items)
    assert c.accepted + c.rejected == c.received
    assert c.rejected == sum(expected_rejects.values())
    assert dict(c.rejected_by_reason) == dict(expected_rejects)
    st = svc.status()
    assert st["plots_received"] == sum(r.n_plots_in for r in reports)
    assert st["plots_rejected"] == sum(sum(r.n_plots_rejected.values()) for r in reports)
    assert st["plots_rejected_by_reason"] == dict(sum((Counter(r.n_plots_rejected) for r in reports), Counter()))
    assert st["plots_rejected_by_reason"]["nan"] == 3  # NaN/inf values; a NaN sigma only defaults the sigma
    assert st["scans_processed"] == 51 and st["reports_published"] == 51 and st["buffered_scans"] == 0
    five = next(r for r in reports if r.scan_id == 5)
    assert five.n_plots_in == 5 and five.n_plots_rejected == {"nan": 3}
    assert five.n_plots_flagged == {"sigma_defaulted": 1} and five.n_candidates == 1


def test_configuration_change_resets_and_is_reported() -> None:
    scans = clean_scans()
    svc = make_service()
    run_items(svc, [Item(codec.encode(s), SCAN_ENC) for s in scans[:10]])
    same = BistaticConfigUpdate(
        header=Header(stamp_ns=scans[9].header.stamp_ns + 1),
        receiver_id="rx1",
        illuminator_id="tx-fm-98.1",
        tx_position_enu_m=[8000.0, 0.0, 300.0],
    )
    moved = same.model_copy(update={"tx_position_enu_m": [8000.0, 10.0, 300.0]})
    enc = codec.encoding_of(BistaticConfigUpdate)
    reports, diags = run_items(svc, [Item(codec.encode(same), enc), Item(codec.encode(moved), enc)])
    assert len(reports) == 1 and reports[0].trigger == "config"
    assert [t.drop_reason for t in reports[0].tracks] == ["reset"]
    assert [d.reason for d in diags] == ["config_reset"]
    assert svc.core.tracks == {} and svc.counters.rejected == 0


def test_end_marker_flushes_and_starts_a_fresh_tracker_with_new_ids() -> None:
    scans = clean_scans()
    svc = make_service()
    end = ScenarioMarker(header=Header(stamp_ns=scans[-1].header.stamp_ns), event="end", scenario="x", seed=0)
    key = keys.scenario("x")
    # the last scan arrives ahead of its predecessor and waits in the reorder buffer until the end marker
    events: list[tuple[str, Any]] = [(IN_KEY, s) for s in scans[:-2]] + [(IN_KEY, scans[-1]), (key, end)]
    first = [o.msg for o in svc.run_offline(events) if o.key == OUT_KEY]
    assert [r.scan_id for r in first][-1] == 51 and "gap_coast" in first[-1].flags
    second = [o.msg for o in svc.run_offline([(IN_KEY, s) for s in scans]) if o.key == OUT_KEY]
    assert len(second) == 51  # the same scan ids again: a new run, not duplicates
    first_ids = {t.track_id for r in first for t in r.tracks}
    assert min(t.track_id for r in second for t in r.tracks) > max(first_ids)  # ids never reused
    core = PclTracker(paper_scenario().tracker_config(preset="paper"))
    expected = [r for s in scans for r in core.step(s)]
    means = [[t.estimate.mean for t in r.tracks] for r in expected]
    assert [[t.estimate.mean for t in r.tracks] for r in second] == means


def test_an_end_marker_that_overtakes_the_last_scans_waits_for_them() -> None:
    """Zenoh orders each subscription, not the sensor key against the scenario key: the end marker may
    arrive before the last scans. The run ends only when the announced number of scans has arrived."""
    scans = clean_scans()
    key = keys.scenario("x")
    end = ScenarioMarker(
        header=Header(stamp_ns=scans[-1].header.stamp_ns),
        event="end",
        scenario="x",
        seed=0,
        published={IN_KEY: len(scans), "fixstream/truth/target1": 51},
    )
    start = ScenarioMarker(header=Header(stamp_ns=0), event="start", scenario="x", seed=0)
    in_order = [o.msg for o in make_service().run_offline([(IN_KEY, s) for s in scans] + [(key, end)])]
    svc = make_service()
    early = [(IN_KEY, s) for s in scans[:40]] + [(key, end)] + [(IN_KEY, s) for s in scans[40:]]
    out = [o.msg for o in svc.run_offline(early)]
    assert out == in_order and len(out) == 51 and svc.resets == 1
    assert {t.track_id for r in out for t in r.tracks} == {1}  # one run, one track: not split at scan 40
    # the next run starts afresh (ids continue), even though the end marker of this run came first again
    again = [o.msg for o in svc.run_offline(early)]
    assert [r.scan_id for r in again] == list(range(1, 52)) and svc.resets == 2  # type: ignore[attr-defined]
    assert {t.track_id for r in again for t in r.tracks} == {2}  # type: ignore[attr-defined]
    # a scan lost on the way: the run is finished by the next run's start marker
    lossy = [(IN_KEY, s) for s in scans[:50]] + [(key, end), (key, start)] + [(IN_KEY, s) for s in scans[:3]]
    out = [o.msg for o in svc.run_offline(lossy)]
    assert svc.resets == 3 and [r.scan_id for r in out] == [*range(1, 51), 1, 2, 3]  # type: ignore[attr-defined]


def test_snapshot_restart_continues_identically(tmp_path: Path) -> None:
    scans = clean_scans()
    snap = tmp_path / "pcl.json"
    whole = [o.msg for o in make_service().run_offline([(IN_KEY, s) for s in scans]) if o.key == OUT_KEY]
    a = make_service(snapshot_file=snap, snapshot_every_scans=5)
    part1 = [o.msg for o in a.run_offline([(IN_KEY, s) for s in scans[:23]]) if o.key == OUT_KEY]
    a.on_stop()  # SIGTERM path
    b = make_service(snapshot_file=snap)
    assert b.core.last_scan_id == 23
    part2 = [o.msg for o in b.run_offline([(IN_KEY, s) for s in scans[23:]]) if o.key == OUT_KEY]
    strip = [r.model_dump(exclude={"header": {"seq"}}) for r in part1 + part2]
    assert strip == [r.model_dump(exclude={"header": {"seq"}}) for r in whole]
    other = make_service(snapshot_file=snap, q_accel_var_m2s4=1.0)  # another configuration: not restored
    assert other.core.last_scan_id is None


def test_settings_mirror_the_core_configuration(monkeypatch: pytest.MonkeyPatch) -> None:
    assert to_config(PclTrackerSettings()) == PclTrackerConfig()
    assert to_config(PclTrackerParams()) == PclTrackerConfig()
    monkeypatch.setenv("FIXSTREAM_PCL_TRACKER_INSTANCE", "rx9-x")
    monkeypatch.setenv("FIXSTREAM_PCL_TRACKER_RECEIVER_ID", "rx9")
    monkeypatch.setenv("FIXSTREAM_PCL_TRACKER_TX_POSITION_ENU_M", "[1, 2, 3]")
    monkeypatch.setenv("FIXSTREAM_PCL_TRACKER_CONFIRM_M", "2")
    monkeypatch.setenv("FIXSTREAM_PCL_TRACKER_CONFIRM_N", "3")
    monkeypatch.setenv("FIXSTREAM_PCL_TRACKER_INIT_COV", "paper_diagonal")
    monkeypatch.setenv("FIXSTREAM_PCL_TRACKER_RB_MIN_CONVERTIBLE_M", "400")
    svc = service_mod.from_environment()
    cfg = svc.config
    assert svc.instance == "rx9-x" and svc.in_key == "fixstream/sensor/rx9/pcl/tx-fm-98.1"
    assert svc.out_key == "fixstream/track/pcl/rx9/tx-fm-98.1"
    assert cfg.geometry.tx_position_enu_m == (1.0, 2.0, 3.0)
    assert (cfg.tracker.confirm_M, cfg.tracker.confirm_N, cfg.tracker.init_cov) == (2, 3, "paper_diagonal")
    assert cfg.limits.rb_min_convertible_m == 400.0
    monkeypatch.setenv("FIXSTREAM_PCL_TRACKER_CONFIRM_N", "1")  # N < M: refused by the core's config
    with pytest.raises(ValueError, match="confirm_N"):
        service_mod.from_environment()


def compose_env(service: str) -> dict[str, str]:
    spec = yaml.safe_load((REPO / "compose.yaml").read_text())["services"][service]
    return {k: str(v) for k, v in spec["environment"].items() if k.startswith("FIXSTREAM_PCL_TRACKER_")}


@pytest.mark.parametrize(
    "scenario",
    ["paper", "clutter", "many", "demo", "manoeuvre_05g", "manoeuvre_1g", "manoeuvre_2g", "crossing", "dense_clutter"],
)
def test_scenarios_name_the_compose_instances_with_their_configuration(
    scenario: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """fixstream mc runs exactly the configuration the stack runs (scenario params = compose environment)."""
    spec = yaml.safe_load((REPO / "scenarios" / f"pcl_tracker_{scenario}.yaml").read_text())
    services = {v["environment"]["FIXSTREAM_PCL_TRACKER_INSTANCE"]: k for k, v in _pcl_services().items()}
    waited = [w.split("/")[1] for w in spec["wait_for"]]
    assert waited and all(w in services for w in waited)
    for est in spec["estimators"]:
        if est["instance"] not in services:
            continue  # a Monte-Carlo-only comparison entry
        for k in list(os.environ):
            if k.startswith("FIXSTREAM_PCL_TRACKER_"):
                monkeypatch.delenv(k)
        for k, v in compose_env(services[est["instance"]]).items():
            monkeypatch.setenv(k, v)
        assert service_mod.from_environment().config == to_config(
            PclTrackerParams.model_validate(est["params"], strict=True)
        )
        assert est["instance"] in waited


def _pcl_services() -> dict[str, Any]:
    spec = yaml.safe_load((REPO / "compose.yaml").read_text())["services"]
    return {k: v for k, v in spec.items() if v.get("command", [None, None, None])[2:3] == ["pcl_tracker"]}


def test_compose_has_one_service_per_pair() -> None:
    pcl = _pcl_services()
    assert set(pcl) == {"pcl_tracker-rx1-fm", "pcl_tracker-rx1-dvbt"}
    pairs = [
        (
            v["environment"]["FIXSTREAM_PCL_TRACKER_RECEIVER_ID"],
            v["environment"]["FIXSTREAM_PCL_TRACKER_ILLUMINATOR_ID"],
        )
        for v in pcl.values()
    ]
    assert len(set(pairs)) == len(pairs)  # two instances on one pair would publish on the same key


def test_plot_forms_through_the_service_match_the_core() -> None:
    """Range-sum/delay and Doppler plots give the same tracks as r_b/v_b plots (to rounding)."""
    base = simulate(paper_scenario(n_scans=15), np.random.default_rng(2))
    forms = simulate(paper_scenario(n_scans=15, range_form="delay", velocity_form="doppler"), np.random.default_rng(2))
    a = [o.msg for o in make_service().run_offline([(IN_KEY, s) for s in base.scans]) if o.key == OUT_KEY]
    b = [o.msg for o in make_service().run_offline([(IN_KEY, s) for s in forms.scans]) if o.key == OUT_KEY]
    for ra, rb in zip(a, b, strict=True):
        assert [t.track_id for t in ra.tracks] == [t.track_id for t in rb.tracks]
        for ta, tb in zip(ra.tracks, rb.tracks, strict=True):
            np.testing.assert_allclose(ta.estimate.mean, tb.estimate.mean, rtol=1e-6, atol=1e-3)


def test_preset_paper_from_environment_and_params(monkeypatch: pytest.MonkeyPatch) -> None:
    """FIXSTREAM_PCL_TRACKER_PRESET=paper and ``preset: paper`` give the digest's configuration; a parameter given
    explicitly wins over the preset; with no parameter the default is the robust preset."""
    for k in list(os.environ):
        if k.startswith("FIXSTREAM_PCL_TRACKER_"):
            monkeypatch.delenv(k)
    default = service_mod.from_environment().config.tracker
    assert (default.preset, default.motion_model, default.confirm_M, default.confirm_N) == ("robust", "imm", 3, 4)
    assert default.burst_initiation == "strongest_snr" and len(default.imm_q_m2s4) == 4
    monkeypatch.setenv("FIXSTREAM_PCL_TRACKER_PRESET", "paper")
    assert service_mod.from_environment().config == PclTrackerConfig.paper()
    paper = PclTrackerConfig.paper().tracker
    assert (paper.motion_model, paper.q_accel_var_m2s4, paper.confirm_M, paper.burst_initiation) == (
        "cv",
        0.01,
        0,
        "suppress",
    )
    monkeypatch.setenv("FIXSTREAM_PCL_TRACKER_CONFIRM_M", "2")
    monkeypatch.setenv("FIXSTREAM_PCL_TRACKER_CONFIRM_N", "3")
    t = service_mod.from_environment().config.tracker
    assert (t.motion_model, t.confirm_M, t.confirm_N) == ("cv", 2, 3)
    p = to_config(PclTrackerParams.model_validate({"preset": "paper", "q_accel_var_m2s4": 1.0}, strict=True))
    assert (p.tracker.motion_model, p.tracker.q_accel_var_m2s4, p.tracker.confirm_M) == ("cv", 1.0, 0)
    with pytest.raises(ValueError, match="motion_model imm"):
        to_config(PclTrackerParams.model_validate({"scheme": "bkf_ukf"}, strict=True))  # IMM has no BKF phase
