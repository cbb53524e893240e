"""Bad input and edge cases of digest 000 section 5.4, the lifecycle of 5.3 and the core's output contract."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from schemas import BeaconRange, Depth, Header, Heading, NavReset, SpeedLog
from schemas.lbl_nav import LblEvent, LblFix
from services.lbl_nav.config import LblNavConfig
from services.lbl_nav.core import LblNavCore
from services.lbl_nav.simulation import SimBeacon, s1_spec, simulate
from shared.service import InputRejected

NS = 1_000_000_000


def _sim(seed: int = 1, t_start: float = -60.0, t_end: float = 20.0, **kw):  # type: ignore[no-untyped-def]
    return simulate(replace(s1_spec(), t_start_s=t_start, t_end_s=t_end, **kw), np.random.default_rng(seed), seed)


def _state_ok(core: LblNavCore) -> None:
    """Every live covariance is finite, exactly symmetric and positive semi-definite; the current 6x6 block is
    positive definite. (Right after launch the augmented 11x11 P is singular by construction: the buffered copy
    is fully correlated with the original, J P_0 J^T.)"""
    if core.bank is None:
        return
    for h in core.bank.hyps:
        assert np.all(np.isfinite(h.X)) and np.all(np.isfinite(h.P))
        assert np.array_equal(h.P, h.P.T)
        ev = np.linalg.eigvalsh(h.P)
        assert ev[0] >= -1e-9 * ev[-1]
        _, Pi = h.current()
        live = np.diag(Pi) > 0.0  # disabled error states (sigma 0) stay exactly zero
        assert np.min(np.linalg.eigvalsh(Pi[np.ix_(live, live)])) > 0.0


def _run(core: LblNavCore, msgs: list) -> tuple[list, list[InputRejected]]:  # type: ignore[type-arg]
    outs, rejected = [], []
    for m in msgs:
        try:
            outs += core.step(m)
        except InputRejected as exc:
            rejected.append(exc)
        _state_ok(core)
    outs += core.flush()
    return outs, rejected


def _hdr(t_s: float) -> Header:
    return Header(stamp_ns=round(t_s * NS))


def _upto(sim, t_rel: float) -> list:  # type: ignore[no-untyped-def]
    """Messages up to and including epoch t_rel (relative to launch)."""
    end = int(sim.stamps_ns[sim.i0]) + round(t_rel * NS)
    return [m for m in sim.messages if m.header.stamp_ns <= end]


def _after(sim, t_rel: float) -> list:  # type: ignore[no-untyped-def]
    end = int(sim.stamps_ns[sim.i0]) + round(t_rel * NS)
    return [m for m in sim.messages if m.header.stamp_ns > end]


# ---- rejections that leave the state untouched ------------------------------------------------------------------
def test_nan_negative_and_zero_ranges_are_rejected() -> None:
    sim = _sim()
    core = LblNavCore(LblNavConfig())
    _run(core, _upto(sim, 5.0))
    t = sim.spec.epoch0_s + 6.0
    bad = [
        (
            BeaconRange.model_construct(header=_hdr(t), beacon_id="B1", range_m=math.nan, travel_time_s=None),
            "non_finite",
        ),
        (BeaconRange.model_construct(header=_hdr(t), beacon_id="B1", range_m=-5.0, travel_time_s=None), "non_positive"),
        (BeaconRange.model_construct(header=_hdr(t), beacon_id="B1", range_m=0.0, travel_time_s=None), "non_positive"),
        (BeaconRange.model_construct(header=_hdr(t), beacon_id="B1", range_m=None, travel_time_s=0.0), "non_positive"),
        (
            BeaconRange.model_construct(header=_hdr(t), beacon_id="B1", range_m=None, travel_time_s=math.inf),
            "non_finite",
        ),
        (SpeedLog.model_construct(header=_hdr(t), v_forward_mps=math.nan, v_starboard_mps=0.0), "non_finite"),
    ]
    before = [h.X.copy() for h in core.bank.hyps]  # type: ignore[union-attr]
    for msg, reason in bad:
        with pytest.raises(InputRejected) as info:
            core.step(msg)
        assert info.value.reason == reason
    assert all(np.array_equal(a, h.X) for a, h in zip(before, core.bank.hyps, strict=True))  # type: ignore[union-attr]
    _state_ok(core)


def test_unknown_beacon_is_rejected_and_never_created() -> None:
    sim = _sim()
    core = LblNavCore(LblNavConfig())
    _run(core, _upto(sim, -50.0))
    with pytest.raises(InputRejected) as info:
        core.step(BeaconRange(header=_hdr(sim.spec.epoch0_s - 49.0), beacon_id="B9", range_m=800.0))
    assert info.value.reason == "unknown_beacon"
    assert "B9" not in core.beacons


def test_stamps_going_backwards_duplicates_late_and_off_grid_inputs() -> None:
    sim = _sim()
    core = LblNavCore(LblNavConfig())
    _run(core, _upto(sim, 5.0))
    t5 = sim.spec.epoch0_s + 5.0
    cases = [
        (SpeedLog(header=_hdr(t5 - 3.0), v_forward_mps=5.0, v_starboard_mps=0.0), "stamp_backwards"),
        (Heading(header=_hdr(t5 - 0.5), heading_rad=0.1), "stamp_backwards"),
        (Depth(header=_hdr(t5 - 2.0), depth_m=30.0), "stamp_backwards"),
        (SpeedLog(header=_hdr(t5), v_forward_mps=5.0, v_starboard_mps=0.0), "duplicate"),
        (BeaconRange(header=_hdr(t5 - 2.0), beacon_id="B2", range_m=990.0), "late"),
        (BeaconRange(header=_hdr(t5 + 1.3), beacon_id="B2", range_m=990.0), "off_epoch"),
    ]
    for msg, reason in cases:
        with pytest.raises(InputRejected) as info:
            core.step(msg)
        assert info.value.reason == reason, msg
    core.step(BeaconRange(header=_hdr(t5 + 1.0), beacon_id="B2", range_m=990.0))
    with pytest.raises(InputRejected) as info:
        core.step(BeaconRange(header=_hdr(t5 + 1.0), beacon_id="B2", range_m=991.0))
    assert info.value.reason == "duplicate"
    _state_ok(core)


def test_physically_impossible_ranges_are_rejected_before_filtering() -> None:
    sim = _sim()
    core = LblNavCore(LblNavConfig())
    _run(core, _upto(sim, -40.0))
    t = sim.spec.epoch0_s - 39.0
    # beacon at 100 m depth, AUV at 30 m: a slant range below 70 - 3*11.2 m is impossible; so is one beyond D_max
    for y in (20.0, 1500.0 + 100.0 + 60.0):
        with pytest.raises(InputRejected) as info:
            core.step(BeaconRange(header=_hdr(t), beacon_id="B1", range_m=y))
        assert info.value.reason == "impossible_range"


def test_pre_launch_range_rate_gate_rejects_a_jump_and_re_anchors_on_consistent_ranges() -> None:
    sim = _sim(t_start=-60.0)
    core = LblNavCore(LblNavConfig())
    _run(core, _upto(sim, -30.0))
    last = [m for m in _upto(sim, -30.0) if isinstance(m, BeaconRange)][-1]
    t = sim.spec.epoch0_s - 29.0
    with pytest.raises(InputRejected) as info:
        core.step(BeaconRange(header=_hdr(t), beacon_id="B1", range_m=last.range_m + 500.0))  # type: ignore[operator]
    assert info.value.reason == "range_rate"
    # a consistent range one epoch later is accepted
    core.step(BeaconRange(header=_hdr(t + 1.0), beacon_id="B1", range_m=last.range_m + 3.0))  # type: ignore[operator]
    # an anchor that was itself an outlier is replaced after two mutually consistent ranges
    core2 = LblNavCore(LblNavConfig(), table=next(m for m in sim.messages if type(m).__name__ == "BeaconTable"))
    core2.step(BeaconRange(header=_hdr(100.0), beacon_id="B1", range_m=1400.0))
    with pytest.raises(InputRejected):
        core2.step(BeaconRange(header=_hdr(101.0), beacon_id="B1", range_m=700.0))
    core2.step(BeaconRange(header=_hdr(102.0), beacon_id="B1", range_m=705.0))


def test_a_late_pre_launch_range_is_inserted_into_its_buffered_epoch() -> None:
    sim = _sim(t_start=-60.0)
    msgs = [
        m
        for m in _upto(sim, -20.0)
        if not (isinstance(m, BeaconRange) and m.header.stamp_ns == int(sim.stamps_ns[sim.i0 - 30]))
    ]
    core = LblNavCore(LblNavConfig())
    _run(core, msgs)
    entry = next(e for e in core.buffer if e.stamp_ns == int(sim.stamps_ns[sim.i0 - 30]))
    assert entry.rows == []
    late = next(
        m for m in sim.messages if isinstance(m, BeaconRange) and m.header.stamp_ns == int(sim.stamps_ns[sim.i0 - 30])
    )
    core.step(late)
    assert len(entry.rows) == 1 and entry.rows[0].value == late.range_m


# ---- launch, lifecycle and outputs ------------------------------------------------------------------------------
def test_lifecycle_waiting_buffering_launch_ambiguous_resolved_tracking() -> None:
    sim = _sim(seed=2, t_start=-150.0, t_end=40.0)
    # the paper's rule (6): the honest preset decides at launch here (the buffered turn), see test_lbl_nav_decision
    outs, rejected = _run(LblNavCore(LblNavConfig(preset="paper")), sim.messages)
    assert len(rejected) <= 2  # at most the odd noisy range dropped by the pre-launch range-rate gate
    fixes = [o for o in outs if isinstance(o, LblFix)]
    statuses = [f.status for f in fixes]
    assert statuses[0] in ("WAITING", "BUFFERING")
    order = []
    for s in statuses:
        if not order or order[-1] != s:
            order.append(s)
    assert order[:3] == ["BUFFERING", "LAUNCH", "AMBIGUOUS"]
    assert "RESOLVED" in order and order[-1] == "TRACKING"
    for f in fixes:
        assert f.header.stamp_ns in set(int(s) for s in sim.stamps_ns)  # stamps come from the data grid
        if f.status in ("LAUNCH", "AMBIGUOUS"):
            assert not f.valid and f.estimate is None and len(f.hypotheses) == 2
            assert sum(h.probability for h in f.hypotheses) == pytest.approx(1.0)
        if f.status in ("RESOLVED", "TRACKING"):
            assert f.valid and f.estimate is not None and f.accepted_hypothesis is not None
            assert f.state is not None and f.sigma_dc_mps is not None
    kinds = [o.kind for o in outs if isinstance(o, LblEvent)]
    assert kinds.count("launch") == 1 and kinds.count("decision") == 1
    launch = next(o for o in outs if isinstance(o, LblEvent) and o.kind == "launch")
    assert launch.grid_nodes == 12 and launch.cluster_sizes == [6, 6] and len(launch.centres_m) == 2


def test_inconsistent_launch_is_postponed_and_the_next_two_beacon_epoch_launches() -> None:
    sim = _sim(seed=3, t_start=-30.0, t_end=10.0)
    t0 = int(sim.stamps_ns[sim.i0])
    msgs = []
    for m in sim.messages:
        if isinstance(m, BeaconRange) and m.header.stamp_ns == t0 and m.beacon_id == "B2":
            m = m.model_copy(update={"range_m": 150.0})  # circles cannot intersect: 150 + ~755 < 1500 - 3 sigma
        msgs.append(m)
    # a second two-beacon epoch 2 s later
    msgs = (
        [m for m in msgs if m.header.stamp_ns <= t0 + 2 * NS]
        + [BeaconRange(header=Header(stamp_ns=t0 + 2 * NS), beacon_id="B2", range_m=985.0)]
        + [m for m in msgs if m.header.stamp_ns > t0 + 2 * NS]
    )
    outs, _ = _run(LblNavCore(LblNavConfig()), msgs)
    ev = [o for o in outs if isinstance(o, LblEvent)]
    assert ev[0].kind == "launch_postponed" and ev[0].reason == "launch_inconsistent"
    first_launch = next(o for o in ev if o.kind == "launch")
    assert first_launch.header.stamp_ns == t0 + 2 * NS
    fix0 = next(o for o in outs if isinstance(o, LblFix) and o.header.stamp_ns == t0)
    assert fix0.status == "BUFFERING"


def test_post_launch_outlier_rejected_for_all_hypotheses_only() -> None:
    sim = _sim(seed=4, t_start=-60.0, t_end=20.0)
    t3 = int(sim.stamps_ns[sim.i0 + 3])
    msgs = [
        m.model_copy(update={"range_m": m.range_m + 400.0})  # type: ignore[operator]
        if isinstance(m, BeaconRange) and m.header.stamp_ns == t3 and m.beacon_id == "B2"
        else m
        for m in sim.messages
    ]
    core = LblNavCore(LblNavConfig(ratio_threshold=1e30))
    outs, _ = _run(core, msgs)
    gate = [o for o in outs if isinstance(o, LblEvent) and o.reason == "innovation_gate"]
    assert len(gate) == 1 and gate[0].header.stamp_ns == t3 and "B2" in gate[0].detail
    fix3 = next(o for o in outs if isinstance(o, LblFix) and o.header.stamp_ns == t3)
    assert fix3.ranges_rejected == 1
    h1, h2 = core.bank.hyps  # type: ignore[union-attr]
    assert list(h1.row_log) == list(h2.row_log)
    assert all(k != "B2" for s, k in h1.row_log if s == t3)


def test_a_range_inconsistent_only_with_the_mirror_is_kept_and_resolves() -> None:
    # a third beacon heard after launch fits the true point but not the mirror: per-hypothesis gating would drop it
    spec = replace(
        s1_spec(),
        beacons=(*s1_spec().beacons, SimBeacon("B3", 900.0, 900.0, 100.0)),
        t_start_s=-30.0,
        t_end_s=15.0,
    )
    sim = simulate(spec, np.random.default_rng(5), 5)
    outs, _ = _run(LblNavCore(LblNavConfig(use_buffered=False, preset="paper")), sim.messages)
    t0 = int(sim.stamps_ns[sim.i0])
    decision = next(o for o in outs if isinstance(o, LblEvent) and o.kind == "decision")
    assert (decision.header.stamp_ns - t0) / NS <= 3.0
    launch_fix = next(o for o in outs if isinstance(o, LblFix) and o.status == "LAUNCH")
    true_id = min(
        launch_fix.hypotheses, key=lambda h: math.dist(h.estimate.mean[:2], (sim.x_m[sim.i0], sim.y_m[sim.i0]))
    )
    assert decision.hypothesis_id == true_id.hypothesis_id
    assert not any(isinstance(o, LblEvent) and o.reason == "innovation_gate" for o in outs)


def test_divergence_triggers_a_reset_and_a_fresh_buffer() -> None:
    sim = _sim(seed=6, t_start=-40.0, t_end=40.0)
    t10 = int(sim.stamps_ns[sim.i0 + 10])
    msgs = [
        m.model_copy(update={"range_m": m.range_m + 300.0})  # type: ignore[operator]
        if isinstance(m, BeaconRange) and m.header.stamp_ns >= t10
        else m
        for m in sim.messages
    ]
    outs, _ = _run(LblNavCore(LblNavConfig(divergence_epochs=5)), msgs)
    kinds = [(o.kind, o.reason) for o in outs if isinstance(o, LblEvent)]
    assert ("divergence", "innovation_gate") in kinds and ("filter_reset", "divergence") in kinds
    reset_at = next(o.header.stamp_ns for o in outs if isinstance(o, LblEvent) and o.kind == "filter_reset")
    assert reset_at <= t10 + 5 * NS
    reset_fix = [o for o in outs if isinstance(o, LblFix) and o.header.stamp_ns == reset_at]
    assert reset_fix[-1].status == "WAITING" and reset_fix[-1].launch_stamp_ns is None
    # a fresh launch follows at the next two-beacon epoch, from a fresh (empty) buffer
    relaunch = [o for o in outs if isinstance(o, LblEvent) and o.kind == "launch" and o.header.stamp_ns > reset_at]
    assert relaunch and "N=0" in relaunch[0].detail


def test_dr_gaps_hold_values_inflate_noise_and_truncate_the_buffer() -> None:
    sim = _sim(seed=7, t_start=-80.0, t_end=30.0)
    t0 = int(sim.stamps_ns[sim.i0])
    gap_post = {t0 + k * NS for k in (20, 21, 22)}
    gap_pre = {t0 - k * NS for k in range(40, 50)}  # 10 s pre-launch gap > dr_hold_max_s
    msgs = [
        m
        for m in sim.messages
        if not (isinstance(m, SpeedLog | Heading) and (m.header.stamp_ns in gap_post or m.header.stamp_ns in gap_pre))
    ]
    core = LblNavCore(LblNavConfig())
    outs, _ = _run(core, msgs)
    ev = [o for o in outs if isinstance(o, LblEvent)]
    trunc = [o for o in ev if o.kind == "buffer_truncated"]
    assert len(trunc) == 1 and trunc[0].reason == "dr_gap"
    fixes = {o.header.stamp_ns: o for o in outs if isinstance(o, LblFix)}
    assert fixes[t0].buffered_epochs <= 40  # only the part after the gap is usable
    assert all(fixes[t].degraded for t in gap_post)
    assert not fixes[t0 + 19 * NS].degraded and not fixes[t0 + 24 * NS].degraded
    # the held DR keeps the fix valid; the computed sigma grows faster across the gap than before it
    if fixes[t0 + 22 * NS].valid and fixes[t0 + 19 * NS].valid:
        v = lambda t: fixes[t].estimate.covariance[0][0] + fixes[t].estimate.covariance[1][1]  # type: ignore[index] # noqa: E731
        assert v(t0 + 22 * NS) > 0.0 and math.isfinite(v(t0 + 22 * NS))


def test_nav_reset_clears_the_estimate() -> None:
    sim = _sim(seed=8)
    core = LblNavCore(LblNavConfig())
    _run(core, _upto(sim, 5.0))
    out = core.step(NavReset(header=_hdr(sim.spec.epoch0_s + 5.5), reason="operator"))
    assert isinstance(out[0], LblEvent) and out[0].kind == "filter_reset" and out[0].reason == "nav_reset"
    assert core.bank is None and core.state == "WAITING"


def test_buffer_overflow_caps_the_buffer() -> None:
    sim = _sim(seed=9, t_start=-120.0, t_end=2.0)
    outs, _ = _run(LblNavCore(LblNavConfig(N_max=50)), sim.messages)
    over = [o for o in outs if isinstance(o, LblEvent) and o.kind == "buffer_overflow"]
    assert len(over) == 1
    launch_fix = next(o for o in outs if isinstance(o, LblFix) and o.status == "LAUNCH")
    assert launch_fix.buffered_epochs == 50 and launch_fix.buffer_dropped >= 70


@pytest.mark.parametrize(
    "b3,expect",
    [((900.0, 800.0), "UNIQUE"), ((0.0, 3000.0), "LAUNCH"), ((3.0, 750.0), "LAUNCH")],
    ids=["non-collinear", "collinear", "near-collinear"],
)
def test_launch_with_three_beacons(b3: tuple[float, float], expect: str) -> None:
    spec = replace(
        s1_spec(),
        beacons=(*s1_spec().beacons, SimBeacon("B3", b3[0], b3[1], 100.0)),
        launch_beacons=("B1", "B2", "B3"),
        reception_m=1e6 if expect == "LAUNCH" and b3[1] == 3000.0 else 1000.0,
        t_start_s=-20.0,
        t_end_s=3.0,
    )
    sim = simulate(spec, np.random.default_rng(11), 11)
    # only the launch epoch has B2 and B3
    t0 = int(sim.stamps_ns[sim.i0])
    msgs = [
        m for m in sim.messages if not (isinstance(m, BeaconRange) and m.beacon_id != "B1" and m.header.stamp_ns != t0)
    ]
    outs, _ = _run(LblNavCore(LblNavConfig()), msgs)
    fix0 = next(o for o in outs if isinstance(o, LblFix) and o.header.stamp_ns == t0)
    assert fix0.status == expect
    truth = (sim.x_m[sim.i0], sim.y_m[sim.i0])
    if expect == "UNIQUE":
        assert fix0.valid and fix0.hypothesis_source == "unique"
        sd = math.sqrt(fix0.estimate.covariance[0][0] + fix0.estimate.covariance[1][1])  # type: ignore[index]
        assert math.dist(fix0.estimate.mean[:2], truth) < 4.0 * sd  # type: ignore[index]
    else:
        assert not fix0.valid and len(fix0.hypotheses) == 2
        assert min(math.dist(h.estimate.mean[:2], truth) for h in fix0.hypotheses) < 60.0


def test_outputs_are_deterministic_and_unvalidated_mode_is_identical() -> None:
    sim = _sim(seed=12, t_start=-60.0, t_end=15.0)
    a, _ = _run(LblNavCore(LblNavConfig()), sim.messages)
    b, _ = _run(LblNavCore(LblNavConfig()), sim.messages)
    c, _ = _run(LblNavCore(LblNavConfig(validate_outputs=False)), sim.messages)
    assert [m.model_dump() for m in a] == [m.model_dump() for m in b]
    assert [m.model_dump() for m in a] == [m.model_dump() for m in c]
    # the unvalidated outputs would have passed validation
    for m in c:
        assert type(m).model_validate(m.model_dump()) == m


def test_travel_time_inputs_equal_range_inputs() -> None:
    a = _sim(seed=13, t_start=-40.0, t_end=10.0)
    b = _sim(seed=13, t_start=-40.0, t_end=10.0, ranges_as_travel_time=True)
    oa, _ = _run(LblNavCore(LblNavConfig()), a.messages)
    ob, _ = _run(LblNavCore(LblNavConfig()), b.messages)
    fa = [o for o in oa if isinstance(o, LblFix) and o.hypotheses]
    fb = [o for o in ob if isinstance(o, LblFix) and o.hypotheses]
    assert len(fa) == len(fb)
    for x, y in zip(fa, fb, strict=True):
        for hx, hy in zip(x.hypotheses, y.hypotheses, strict=True):
            assert math.dist(hx.estimate.mean, hy.estimate.mean) < 1e-6


@pytest.mark.parametrize(
    "kw", [{"heading_linearisation": "estimate"}, {"ekf_iterations": 3}, {"sigma_w_form": "linear"}]
)
def test_options_run_and_resolve(kw: dict) -> None:  # type: ignore[type-arg]
    sim = _sim(seed=14, t_start=-150.0, t_end=25.0)
    outs, _ = _run(LblNavCore(LblNavConfig(**kw)), sim.messages)
    d = [o for o in outs if isinstance(o, LblEvent) and o.kind == "decision"]
    assert len(d) == 1
    last = [o for o in outs if isinstance(o, LblFix)][-1]
    assert last.valid and math.dist(last.estimate.mean[:2], (sim.x_m[-1], sim.y_m[-1])) < 50.0  # type: ignore[index]


def test_dead_reckoning_only_when_no_range_is_used_for_a_while() -> None:
    sim = _sim(seed=15, t_start=-150.0, t_end=80.0)
    t_cut = int(sim.stamps_ns[sim.i0 + 30])
    msgs = [m for m in sim.messages if not (isinstance(m, BeaconRange) and m.header.stamp_ns > t_cut)]
    outs, _ = _run(LblNavCore(LblNavConfig(dr_only_after_s=30.0)), msgs)
    fixes = {o.header.stamp_ns: o for o in outs if isinstance(o, LblFix)}
    assert fixes[t_cut].status in ("TRACKING", "RESOLVED")
    assert fixes[t_cut + 29 * NS].status == "TRACKING"
    assert all(fixes[t_cut + k * NS].status == "DR_ONLY" and fixes[t_cut + k * NS].valid for k in range(30, 50))
    # the computed uncertainty grows while dead reckoning
    var = [fixes[t_cut + k * NS].estimate.covariance[0][0] for k in (30, 49)]  # type: ignore[index]
    assert var[1] > var[0]
