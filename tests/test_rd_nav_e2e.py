"""AUV group navigation over real processes and a real Zenoh router (issue 5).

* End to end: the demo (``scenarios/rd_demo.yaml``: five AUVs, a role swap) through
  ``fixstream up router recorder player coordinator-group1 rd_nav-auv3 rd_nav-auv4`` (the repository's compose.yaml,
  rate 0). The loop is closed over Zenoh: the player waits for the coordinator service's replies and the simulated
  group obeys them. What the recorder wrote must equal, message for message and header included, the offline run
  of the same seed: the player's events = ``scenario_events`` (the coordinator's in-process twin in the loop), and
  each service's outputs = the same service (built from the compose file's environment) through ``run_offline``
  on those events; the fixes also equal the core in-process. The metrics of the recording (``run_metrics`` on what
  the services published, as ``fixstream report`` computes them) equal ``fixstream mc``'s (``run_core``).
* Bad input over a real router: every case of ``test_rd_nav_service.py`` on the wire to a ``fixstream run rd_nav``
  process; each is reported with its reason, the service stays alive, its status counters add up, and its
  outputs equal its offline twin's on the same bytes.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import REPO
from stack_support import (
    as_composed,
    delivered,
    framed,
    live_run_equals_offline,
    on_key,
    player_waited_for,
    recorded_by_topic,
    run_up,
    without_source_seq,
)
from test_rd_nav_service import (
    AUV,
    FLEET,
    bad_items,
    check_bad_input_run,
    cycle_errors,
    demo,
    make_service,
    offline_twin,
    truth_ne,
    vehicle_feed,
)

from schemas import Message
from schemas.rd_nav import BeaconAssignment, CoordinatorReply, DepartureGrant, RdNavFix
from services.coordinator import mc as coordinator_mc
from services.coordinator import service as coordinator_service
from services.coordinator.service import assignment_key, grant_key, reply_key
from services.player.simulators import Event
from services.rd_nav import mc as rd_mc
from services.rd_nav import service as rd_service
from services.rd_nav.core import RdNavCore
from services.rd_nav.service import cycle_key, ekf_key, fix_key, output_key
from shared import keys
from shared.errors import InputRejected
from tools.montecarlo import jsonable

pytestmark = pytest.mark.e2e

SCENARIO = REPO / "scenarios" / "rd_demo.yaml"
SERVICES = ["coordinator-group1", "rd_nav-auv3", "rd_nav-auv4"]


def test_the_closed_loop_through_the_stack_gives_the_offline_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log, recordings = run_up(tmp_path, SCENARIO, SERVICES, timeout_s=180)
    for alive in ("coordinator/group1", "rd_nav/auv3", "rd_nav/auv4"):
        assert player_waited_for(log, f"fixstream/alive/{alive}")
    assert "exchange_timeout" not in log
    got = recorded_by_topic(recordings)
    scenario, events = demo()
    feed = framed(scenario, [(e.key, e.msg) for e in events])

    # the player published exactly the offline events: the group took the decisions the in-process twin takes
    published = {e.key for e in events}
    for key in published:
        assert got.get(key, []) == [e.msg for e in events if e.key == key], key

    # the coordinator service: its outputs equal its offline twin's, message for message
    co = as_composed(monkeypatch, "coordinator-group1", coordinator_service.build, SCENARIO)
    co_out = co.run_offline(delivered(co, feed))
    co_keys = {o.key for o in co_out}
    assert co_keys == {assignment_key("group1"), grant_key("group1", "auv3"), reply_key("group1")}
    for key in co_keys:
        assert got.get(key, []) == on_key(co_out, key), key
    assert keys.diag("coordinator", "group1") not in got
    # ... with the role swap: epochs 1, 2, 3, the last without auv3, then auv3's grant
    assigned = [m for m in got[assignment_key("group1")] if isinstance(m, BeaconAssignment)]
    assert [a.epoch for a in assigned] == [1, 2, 3]
    assert "auv3" in (assigned[1].leader_id, *assigned[1].follower_ids)
    assert "auv3" not in (assigned[2].leader_id, *assigned[2].follower_ids)
    (grant,) = got[grant_key("group1", "auv3")]
    assert isinstance(grant, DepartureGrant) and grant.epoch == 3
    replies = [m for m in got[reply_key("group1")] if isinstance(m, CoordinatorReply)]
    uplink = [k for k, _ in feed if k.startswith("fixstream/group/group1/uplink/")]
    assert len(replies) == len(uplink) and all(r.rejected is None for r in replies)

    # every rd_nav: outputs equal the offline twin's and the core's in-process
    for auv in ("auv3", "auv4"):
        svc = as_composed(monkeypatch, f"rd_nav-{auv}", rd_service.build, SCENARIO)
        vfeed = delivered(svc, feed)
        out = svc.run_offline(vfeed)
        out_keys = {o.key for o in out}
        assert {fix_key(auv), ekf_key(auv), cycle_key(auv)} <= out_keys
        for key in out_keys:
            assert got.get(key, []) == on_key(out, key), (auv, key)
        core = RdNavCore(svc.core_config)
        expected: list[Message] = []
        for _, msg in vfeed[1:-1]:
            try:
                expected += [m for m in core.step(msg) if output_key(auv, m) == fix_key(auv)]
            except InputRejected:  # the twin refused it too (reported on diag)
                continue
        assert without_source_seq(got[fix_key(auv)]) == without_source_seq(expected)
        errs = cycle_errors(got[fix_key(auv)], truth_ne(events, auv))
        assert len(errs) >= 6 and max(e for _, e in errs) < 4.0, (auv, errs)

        # the recording's metrics (what fixstream report computes) = fixstream mc's
        outputs = [Event(m.header.stamp_ns, k, m) for k in sorted(out_keys) for m in got[k]]
        outputs.sort(key=lambda ev: ev.stamp_ns)
        params = {"vehicle": auv}
        from_recording = jsonable(rd_mc.run_metrics(outputs, list(events), params, scenario))
        in_process = jsonable(rd_mc.run_core(list(events), params, scenario))
        for k in rd_mc.OFFLINE_ONLY:
            in_process.pop(k)
        assert from_recording == in_process, auv
        assert from_recording["pf"]["n"] >= 4 and from_recording["pf_summary"]["rms_m"] < 2.5

    co_events = [Event(m.header.stamp_ns, k, m) for k in sorted(co_keys) for m in got[k]]
    co_events.sort(key=lambda ev: ev.stamp_ns)
    co_metrics = coordinator_mc.run_metrics(co_events, list(events), {"group": "group1"}, scenario)
    assert co_metrics == coordinator_mc.run_core(list(events), {"group": "group1"}, scenario)
    assert co_metrics["grants_with_too_few_others"] == 0 and co_metrics["assigned_non_beacons"] == 0
    assert co_metrics["fewest_beacons_after_preliminary"] == 3 and co_metrics["epochs_increasing"]


def test_bad_input_over_a_real_router(router: str) -> None:
    svc = make_service("bad1", auv_id=AUV, fleet_ids=FLEET)
    items, expected, step_at = bad_items(vehicle_feed(svc))
    twin = offline_twin(items)
    check_bad_input_run(twin, expected, step_at)
    env = {"FIXSTREAM_RD_NAV_AUV_ID": AUV, "FIXSTREAM_RD_NAV_FLEET_IDS": json.dumps(FLEET)}
    listen = [f"fixstream/fix/rd/{AUV}/**"]  # the fixes and, below them, the EKF's and the cycles
    run = live_run_equals_offline(router, "rd_nav", "bad1", listen, items, twin.outbox, expected, **env)
    status, received, diags = run.status, run.received, run.diags
    assert status["events"] == dict(twin.events) and status["auv_id"] == AUV
    assert not status["scenario"]["end_pending"] and status["scenario"]["ends"] == {"complete": 1}
    assert all(d.key.startswith(f"fixstream/sensor/{AUV}/") for d in diags)
    fixes = [m for m in received[fix_key(AUV)] if isinstance(m, RdNavFix)]
    assert fixes and all(f.auv_id == AUV for f in fixes)
