"""PCL tracker over real processes and a real Zenoh router.

* E1 (digest 003 §4.4) through ``fixstream up router recorder player pcl_tracker-rx1-fm`` (the repository's
  compose.yaml, the paper scenario file, rate 0): the scan reports in the MCAP equal, message for message
  (header included), what the service built the same way produces offline from the same scenario events
  framed by the player's start and end markers; and the run meets E1's criteria with E2's labels (the
  compose instance runs the default configuration, M/N = 3/4).
* The bad-input stream of ``test_pcl_tracker_service.py`` published raw over a router into
  ``fixstream run pcl_tracker``: every case is diagnosed with its reason, the process stays up, its status
  counters add up, and the tracks equal the offline run's (which equal the clean stream's).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, wait_until
from stack_support import as_composed, delivered, framed, live_service, recorded_by_topic, run_up, scenario_feed
from test_pcl_tracker_service import (
    IN_KEY,
    OUT_KEY,
    clean_scans,
    dirty_stream,
    make_service,
    run_items,
    track_view,
)

from schemas import Message
from schemas.pcl_tracker import PclScanReport
from services.pcl_tracker import service as service_mod
from services.player.scenario import load_scenario

pytestmark = pytest.mark.e2e

SCENARIO = REPO / "scenarios" / "pcl_tracker_paper.yaml"
STACK_SERVICE = "pcl_tracker-rx1-fm"


def offline_outputs(
    monkeypatch: pytest.MonkeyPatch, scenario_path: Path, stack_service: str
) -> dict[str, list[Message]]:
    """What a stack service publishes for the scenario, per key, computed without Zenoh."""
    # from_environment: what build() does, without freezing this process's GC
    svc = as_composed(monkeypatch, stack_service, service_mod.from_environment, scenario_path)
    scenario = load_scenario(scenario_path)
    out: dict[str, list[Message]] = {}
    for o in svc.run_offline(delivered(svc, framed(scenario, scenario_feed(scenario)))):
        out.setdefault(o.key, []).append(o.msg)
    return out


def test_e1_through_the_stack_equals_the_offline_service(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out, recordings = run_up(tmp_path, SCENARIO, [STACK_SERVICE])
    assert f"[up] {STACK_SERVICE} ready: fixstream/alive/pcl_tracker/rx1-fm" in out
    by_topic = recorded_by_topic(recordings)
    recorded = by_topic[OUT_KEY]
    offline = offline_outputs(monkeypatch, SCENARIO, STACK_SERVICE)
    assert set(offline) == {OUT_KEY}  # a clean stream: no diagnostic offline ...
    assert not [t for t in by_topic if t.startswith("fixstream/diag/")]  # ... nor in the stack
    assert len(recorded) == 51
    assert recorded == offline[OUT_KEY]  # message for message, header (source, seq, stamp) included

    # the instance runs the default configuration (M/N = 3/4): digest E1/E2 on this run: one id, created at
    # scan 2 (t = 3 s), TENTATIVE at scans 2-4, CONFIRMED at scan 5 (third hit) and after, never dropped,
    # < 250 m at the end
    reports = [m for m in recorded if isinstance(m, PclScanReport)]
    assert len(reports) == 51
    assert {t.track_id for r in reports for t in r.tracks} == {1}
    first = reports[1].tracks[0]
    assert (first.created_scan_id, first.status, reports[1].t_s) == (2, "TENTATIVE", 3.0)
    assert [r.tracks[0].status for r in reports[1:5]] == ["TENTATIVE"] * 3 + ["CONFIRMED"]
    assert all(t.status == "CONFIRMED" for r in reports[4:] for t in r.tracks)
    c = np.deg2rad(256.0)
    truth = np.array([9000.0, 5000.0, 1000.0]) + 150.0 * 200.0 * np.array([np.sin(c), np.cos(c), 0.0])
    assert float(np.linalg.norm(np.array(reports[-1].tracks[0].estimate.mean[:3]) - truth)) < 250.0


def test_demo_with_two_instances_equals_the_offline_services(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two pairs, clutter, a turn and a late target; the end marker may overtake the last scans of both keys."""
    demo = REPO / "scenarios" / "pcl_tracker_demo.yaml"
    services = ["pcl_tracker-rx1-fm", "pcl_tracker-rx1-dvbt"]
    _, recordings = run_up(tmp_path, demo, services)
    by_topic = recorded_by_topic(recordings)
    for svc_name in services:
        for key, msgs in offline_outputs(monkeypatch, demo, svc_name).items():
            assert by_topic[key] == msgs, (svc_name, key)
    tracks = {k for k in by_topic if k.startswith("fixstream/track/")}
    assert tracks == {"fixstream/track/pcl/rx1/tx-fm-98.1", "fixstream/track/pcl/rx1/tx-dvbt-530"}


def test_bad_input_over_a_real_router(router: str) -> None:
    instance = "bad"
    items = dirty_stream(clean_scans())
    expected_reports, expected_diags = run_items(make_service(instance), items)

    with live_service(router, "pcl_tracker", instance, [OUT_KEY], FIXSTREAM_PCL_TRACKER_PRESET="paper") as live:
        live.put_raw((IN_KEY, it.payload, it.encoding) for it in items)
        live.wait_status(lambda st: st["counters"]["received"] == len(items), timeout_s=60)
        diag_key = live.diag_key
        assert wait_until(
            lambda: live.count(OUT_KEY) == len(expected_reports) and live.count(diag_key) == len(expected_diags),
            timeout=30,
        )
        status = live.status()
        assert live.proc.poll() is None  # still running after all of it
    got, diags = live.received[OUT_KEY], live.received[diag_key]

    assert got == expected_reports  # message for message, as the offline run of the same input
    assert diags == expected_diags
    reports = [r for r in got if isinstance(r, PclScanReport)]
    clean = [o.msg for o in make_service("clean").run_offline([(IN_KEY, s) for s in clean_scans()]) if o.key == OUT_KEY]
    assert track_view(reports) == track_view(clean)  # type: ignore[arg-type]
    expected_rejects = {it.reject for it in items if it.reject}
    assert {d.reason for d in diags} >= expected_rejects | {ev for it in items for ev in it.events}  # type: ignore[attr-defined]
    c = status["counters"]
    assert c["received"] == len(items) and c["accepted"] + c["rejected"] == c["received"]
    assert set(c["rejected_by_reason"]) == expected_rejects
    assert status["plots_received"] == sum(r.n_plots_in for r in reports)
    assert status["plots_rejected"] == sum(sum(r.n_plots_rejected.values()) for r in reports)
    assert status["scans_processed"] == 51 and status["reports_published"] == 51
    assert status["live_tracks"] == 1 and status["confirmed"] == 1
