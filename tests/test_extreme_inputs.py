"""Schema-valid but extreme inputs that once stalled a service, exhausted its memory or failed every later message
(an estimator audit, November 2026). Each test feeds a service its demo run in-process, with one kind of extreme
value put in, and asserts what bounds the damage: memory, work done (counted, never timed), refusals with a reason,
outputs that encode.
"""

from __future__ import annotations

import tracemalloc
from collections import Counter
from typing import Any

import pytest
from test_hostile_inputs import build, clean_run

from schemas import Diagnostic, Message, ScenarioMarker, Truth
from schemas.base import VEC_COMPONENT_MAX
from schemas.rd_nav import VehicleStatus
from services.rd_nav import drift
from shared import codec
from shared.service import Service


def feed(svc: Service, events: list[tuple[str, Message]]) -> list[Any]:
    """The events as the player would publish them (its source, a seq per key); the outputs they caused."""
    seq: Counter[str] = Counter()
    source = "player/default"
    start = len(svc.outbox)
    for key, m in events:
        if isinstance(m, ScenarioMarker):
            source = m.header.source
            payload = codec.encode(m)
        else:
            payload = codec.encode_stamped(m, source, seq[key])
            seq[key] += 1
        svc.process(key, payload, codec.encoding_of(type(m)), rx_time_ns=0)
    return svc.outbox[start:]


def restamped(m: Message, stamp_ns: int) -> Message:
    return m.model_copy(update={"header": m.header.model_copy(update={"stamp_ns": stamp_ns})})


def internal_errors(svc: Service) -> int:
    return svc.counters.rejected_by_reason.get("internal_error", 0) + svc.counters.publish_failed


def started(name: str) -> Service:
    svc = build(name)
    svc.run_offline([])
    return svc


def test_a_jump_in_scan_id_costs_no_memory_in_proportion_to_it() -> None:
    """The reorder buffer once listed every scan id it skipped: a jump of 1e8 took 3.8 GB (the schema allows 2**62)."""
    events, _ = clean_run("pcl_tracker")
    scans = [i for i, (_, m) in enumerate(events) if type(m).__name__ == "BistaticScan"]
    jumped = list(events)
    for i in scans[10:]:
        k, m = jumped[i]
        jumped[i] = (k, m.model_copy(update={"scan_id": m.scan_id + 10**7}))
    svc = started("pcl_tracker")
    feed(svc, jumped[: scans[10]])
    tracemalloc.start()
    try:
        outs = feed(svc, jumped[scans[10] :])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 20e6, f"{peak / 1e6:.0f} MB for the scans after the jump (a list of 1e7 ids is ~380 MB)"
    assert internal_errors(svc) == 0
    reports = [o.msg for o in outs if type(o.msg).__name__ == "PclScanReport"]
    assert len(reports) == len(scans) - 10  # one report per scan, the jumped ones too
    assert "gap_reset" in reports[0].flags  # max_gap_scans: the jump is a gap the tracker restarts after
    assert sum(len(r.tracks) for r in reports[5:]) > 0  # and it tracks again


def test_one_sample_stamped_days_ahead_costs_a_bounded_prediction(monkeypatch: pytest.MonkeyPatch) -> None:
    """rd_nav predicted a gap in steps of q_step_s: one Depth sample stamped 10 days ahead took 86,400 steps (7.5 s),
    one at the schema's largest stamp would have taken about 11 h. Now at most max_predict_steps."""
    events, _ = clean_run("rd_nav")
    i = max(j for j, (_, m) in enumerate(events) if type(m).__name__ == "Depth" and j < 0.6 * len(events))
    svc = started("rd_nav")
    feed(svc, events[:i])
    steps = 0
    step = drift.DriftModel.step

    def counted(self: drift.DriftModel, *args: Any) -> drift.DriftStep:
        nonlocal steps
        steps += 1
        return step(self, *args)

    monkeypatch.setattr(drift.DriftModel, "step", counted)
    k, m = events[i]
    feed(svc, [(k, restamped(m, m.header.stamp_ns + 10 * 86_400 * 10**9))])
    assert 0 < steps <= 1000, steps  # max_predict_steps (500) per prediction; 86,400 before
    assert internal_errors(svc) == 0


def test_a_tiny_cycle_period_leaves_every_fix_encodable() -> None:
    """cycle_period_s = 1e-300 (the schema asks > 0) made cycles_since_update 1e301, which msgpack cannot encode."""
    events, _ = clean_run("rd_nav")
    tiny = [
        (k, m.model_copy(update={"cycle_period_s": 1e-300}) if type(m).__name__ == "BeaconAssignment" else m)
        for k, m in events
    ]
    svc = started("rd_nav")
    outs = feed(svc, tiny)
    fixes = [o.msg for o in outs if type(o.msg).__name__ == "RdNavFix"]
    assert fixes and max(f.cycles_since_update for f in fixes) <= 2**31 - 1
    for f in fixes:
        codec.encode_stamped(f, "rd_nav/x", 0)
    assert internal_errors(svc) == 0


@pytest.mark.parametrize("sigma_r_m", [1e5, 1e7, 1e9])
def test_a_plot_with_a_huge_range_sigma_is_an_uninformative_update_not_a_failure(sigma_r_m: float) -> None:
    """ln det S by the rule of Sarrus came out of cancellation <= 0 for an S spanning many orders of magnitude, and
    the logarithm's ValueError was an internal_error. The plot is now a (nearly uninformative) update."""
    events, _ = clean_run("attitude")
    plots = [i for i, (_, m) in enumerate(events) if type(m).__name__ == "RadarPlot"]
    wide = list(events)
    k, m = wide[plots[60]]
    wide[plots[60]] = (k, m.model_copy(update={"sigma_r_m": sigma_r_m}))
    svc = started("attitude")
    outs = feed(svc, wide)
    assert internal_errors(svc) == 0
    estimates = [o.msg for o in outs if type(o.msg).__name__ == "AttitudeEstimate"]
    assert len(estimates) == len(plots)  # one per plot, the wide one's too


def test_a_stamp_jump_beyond_the_epoch_limit_is_a_time_jump_not_a_flood() -> None:
    """lbl_nav closed every epoch of a jump up to 100,000 of them: 15 s and 99,000 DR_ONLY fixes for one message."""
    events, _ = clean_run("lbl_nav")
    i = 150
    gap_ns = 10_000 * 10**9
    jumped = events[:i] + [
        (k, m if isinstance(m, ScenarioMarker) else restamped(m, m.header.stamp_ns + gap_ns)) for k, m in events[i:]
    ]
    svc = started("lbl_nav")
    outs = feed(svc, jumped)
    assert internal_errors(svc) == 0
    jumps = [
        o.msg for o in outs if getattr(o.msg, "reason", None) == "time_jump" or getattr(o.msg, "event", None) == "reset"
    ]
    assert jumps, Counter(type(o.msg).__name__ for o in outs)
    clean = feed(started("lbl_nav"), events)
    assert len(outs) < len(clean) + 100  # not 10,000 fixes of held DR


def test_vector_components_beyond_a_million_km_are_refused_by_the_schema() -> None:
    """Vec2/Vec3 were unbounded: 1e300 overflowed to inf inside rd_nav's and pcl_tracker's filters and failed every
    later message of the run."""
    from pydantic import ValidationError

    from schemas import Header

    h = Header(stamp_ns=0, frame_id="local_enu")
    Truth(header=h, platform="p", position_m=[VEC_COMPONENT_MAX, -VEC_COMPONENT_MAX, 0.0])
    for bad in (1e300, 1.0001 * VEC_COMPONENT_MAX, -1e10):
        with pytest.raises(ValidationError):
            Truth(header=h, platform="p", position_m=[0.0, bad, 0.0])
    events, _ = clean_run("rd_nav")
    j = next(j for j, (_, m) in enumerate(events) if isinstance(m, VehicleStatus) and m.position_ned_m is not None)
    k, m = events[j]
    at_bound = list(events)
    at_bound[j] = (k, m.model_copy(update={"position_ned_m": [VEC_COMPONENT_MAX, 0.0, 0.0]}))
    svc = started("rd_nav")
    feed(svc, at_bound)
    assert internal_errors(svc) == 0
    assert not any(isinstance(o.msg, Diagnostic) and o.msg.reason == "internal_error" for o in svc.outbox)
