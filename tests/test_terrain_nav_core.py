"""The terrain navigator's core through ``step()``: outputs, bad input, resets, grouping, memory, options."""

from __future__ import annotations

import dataclasses
import math
import pickle
from collections import Counter

import numpy as np
import pytest

from schemas import BaroAltitude, Depth, Header, InsSample, Message, NavReset, RadioAltimeter
from schemas.terrain_nav import TerrainFix, TerrainVerdict
from services.terrain_nav.base_algorithm import BaseRecurrentSearch
from services.terrain_nav.calibration import derive_n_limits, n_max_from
from services.terrain_nav.config import TerrainNavConfig
from services.terrain_nav.core import TerrainNavigator
from services.terrain_nav.metrics import fix_errors_cells
from services.terrain_nav.offline import run_flight
from services.terrain_nav.resampler import CellMeasurement, CellResampler
from services.terrain_nav.simulation import FailureSpec, FlightScenario, SimulatedFlight, simulate
from services.terrain_nav.sync import Synchroniser
from shared.service import InputRejected

SC = FlightScenario()

PAPER = TerrainNavConfig(preset="paper")  # the digest's configuration: these tests check the digest's algorithm


@pytest.fixture(scope="module")
def flight() -> SimulatedFlight:
    return simulate(SC, 7)


def _feed(nav: TerrainNavigator, msgs: list[Message]) -> tuple[list[Message], Counter[str]]:
    out: list[Message] = []
    rejected: Counter[str] = Counter()
    for m in msgs:
        try:
            out.extend(nav.step(m))
        except InputRejected as exc:
            rejected[exc.reason] += 1
    return out, rejected


def _snapshot(nav: TerrainNavigator) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    return nav.bank.x.copy(), nav.bank.P.copy(), nav.F.copy(), nav.N_valid, nav.total_meas


def _assert_state_valid(nav: TerrainNavigator) -> None:
    P = nav.bank.P
    assert np.allclose(P, P.T, rtol=0, atol=1e-12 * np.abs(P).max())
    assert np.all(np.linalg.eigvalsh(P) > 0)
    assert np.all(np.isfinite(nav.bank.x)) and np.all(np.isfinite(nav.F))


def _hdr(t: float) -> Header:
    return Header(stamp_ns=round(t * 1e9), frame_id="map")


# --- outputs ---------------------------------------------------------------------------------------------------


def test_one_verdict_per_group_and_a_fix_after_each_valid_verdict(flight: SimulatedFlight) -> None:
    nav = TerrainNavigator(flight.world.ref_map, PAPER)
    out, rejected = _feed(nav, list(flight.messages()))
    assert not rejected
    verdicts = [m for m in out if isinstance(m, TerrainVerdict)]
    fixes = [m for m in out if isinstance(m, TerrainFix)]
    assert len(verdicts) == nav.total_meas // 4 == nav.n_evaluations
    assert [v.n_measurements for v in verdicts] == [4 * (k + 1) for k in range(len(verdicts))]
    assert fixes, "informative terrain gives fixes"
    for k, m in enumerate(out):
        if isinstance(m, TerrainFix):
            prev = out[k - 1]
            assert isinstance(prev, TerrainVerdict) and prev.valid and prev.state == "FIX"
            assert m.verdict == prev and m.header.stamp_ns == prev.header.stamp_ns
            assert m.header.frame_id == "map"
            assert m.i_star == prev.i_star and m.j_star == prev.j_star
    # stamps come from the data: within the flight's time span, non-decreasing
    stamps = [m.header.stamp_ns for m in out]
    assert stamps == sorted(stamps)
    assert stamps[0] >= flight.stamp_ns(0) and stamps[-1] <= flight.stamp_ns(flight.tau.size - 1)
    assert verdicts[0].state == "ACQUIRING" and not verdicts[0].c1_enough_data
    # corrected position = INS position at t_fix + correction; it lands near the true position
    for f in fixes:
        k = int(np.argmin(np.abs(flight.t - f.header.stamp_ns * 1e-9)))
        x_corr, z_corr = f.estimate.mean
        assert x_corr - f.dx_m == pytest.approx(flight.x_ins[k], abs=15.0)  # INS moves 10 m per tick
        assert abs(z_corr - flight.z_true[k]) < 125.0
        assert f.h_corr_m == pytest.approx(f.vertical.mean[f.vertical.index("dh")] + flight.h_ins[k], abs=1.0)


def test_same_input_gives_the_same_output(flight: SimulatedFlight) -> None:
    a = run_flight(flight, PAPER).outputs
    b = run_flight(flight, PAPER).outputs
    assert a == b and len(a) > 10


def test_checkpoint_by_pickle_continues_identically(flight: SimulatedFlight) -> None:
    msgs = list(flight.messages())
    nav = TerrainNavigator(flight.world.ref_map, PAPER)
    half = len(msgs) // 2
    _feed(nav, msgs[:half])
    clone = pickle.loads(pickle.dumps(nav))
    rest_a, _ = _feed(nav, msgs[half:])
    rest_b, _ = _feed(clone, msgs[half:])
    assert rest_a == rest_b and any(isinstance(m, TerrainFix) for m in rest_a)


# --- bad input (§5.6) -------------------------------------------------------------------------------------------


def test_bad_inputs_are_rejected_and_leave_the_state_unchanged(flight: SimulatedFlight) -> None:
    msgs = list(flight.messages())
    nav = TerrainNavigator(flight.world.ref_map, PAPER)
    _feed(nav, msgs[:800])  # well into the flight
    last_ins = next(m for m in reversed(msgs[:800]) if isinstance(m, InsSample))
    last_t = last_ins.header.stamp_ns * 1e-9
    before = _snapshot(nav)
    bad: list[tuple[Message, str]] = [
        (RadioAltimeter.model_construct(header=_hdr(last_t + 0.01), h_agl_m=math.nan, valid=True), "non_finite"),
        (RadioAltimeter(header=_hdr(last_t + 0.02), h_agl_m=400.0, valid=False), "ra_invalid"),
        (RadioAltimeter(header=_hdr(last_t - 1.0), h_agl_m=400.0), "stamp_not_increasing"),
        (RadioAltimeter(header=_hdr(last_t), h_agl_m=400.0), "stamp_not_increasing"),  # duplicate stamp
        (InsSample(header=_hdr(last_t - 0.5), x_m=0.0, z_m=0.0, h_m=1000.0), "stamp_not_increasing"),
        (InsSample(header=_hdr(last_t + 0.03), x_m=0.0, z_m=0.0, h_m=1000.0, valid=False), "ins_invalid"),
        (
            InsSample.model_construct(
                header=_hdr(last_t + 0.04),
                x_m=math.inf,
                z_m=0.0,
                h_m=1.0,
                vx_mps=None,
                vz_mps=None,
                vh_mps=None,
                valid=True,
            ),
            "non_finite",
        ),
        (RadioAltimeter(header=_hdr(last_t + 0.5), h_agl_m=400.0), "unsynchronised"),  # INS 0.5 s old
        (Depth(header=_hdr(last_t + 0.6), depth_m=3.0), "unsupported_type"),
    ]
    for msg, reason in bad:
        with pytest.raises(InputRejected) as info:
            nav.step(msg)
        assert info.value.reason == reason, (msg, info.value)
        after = _snapshot(nav)
        for x, y in zip(before, after, strict=True):
            assert np.array_equal(x, y)
        _assert_state_valid(nav)
    assert nav.counters["stamp_not_increasing"] == 3
    # and the navigator carries on normally afterwards
    out, rejected = _feed(nav, msgs[800:])
    assert not rejected and any(isinstance(m, TerrainFix) for m in out)


def test_ins_gap_gives_a_gap_verdict_and_drops_unsynchronisable_ra(flight: SimulatedFlight) -> None:
    sc = SC.model_copy(update={"failures": (FailureSpec(kind="ins_gap", onset_s=30.0, duration_s=1.0),)})
    fl = simulate(sc, 7)
    nav = TerrainNavigator(fl.world.ref_map, PAPER)
    out, rejected = _feed(nav, list(fl.messages()))
    gaps = [m for m in out if isinstance(m, TerrainVerdict) and m.state == "GAP"]
    assert len(gaps) == 1 and gaps[0].header.stamp_ns == fl.stamp_ns(round(31.0 * 20))
    assert not gaps[0].valid and gaps[0].f_min_per_n_m2 is None
    # RA samples at 30.20 .. 30.95 s are > 0.2 s from the last INS sample (29.95 s): refused on arrival;
    # those at 30.00 .. 30.15 s wait and are dropped when the INS resumes at 31.0 s
    assert rejected == Counter({"unsynchronised": 16})
    assert nav.counters["ra_dropped_unsynchronised"] == 4 and "4 queued RA samples dropped" in gaps[0].detail
    _assert_state_valid(nav)


def test_out_of_zone_verdicts_at_most_once_per_second() -> None:
    sc = SC.model_copy(update={"start_cell": (10, 50), "offset_max_cells": 2.0, "duration_s": 10.0})
    fl = simulate(sc, 3)
    out, rejected = _feed(TerrainNavigator(fl.world.ref_map, PAPER), list(fl.messages()))
    assert not rejected
    ooz = [m for m in out if isinstance(m, TerrainVerdict)]
    assert all(v.state == "OUT_OF_ZONE" and not v.valid for v in ooz)  # the zone starts at cell 25
    t = np.array([v.header.stamp_ns for v in ooz]) * 1e-9
    assert len(ooz) == 10 and np.all(np.diff(t) >= 1.0 - 1e-9)


def test_nav_reset_clears_the_estimator_but_keeps_the_map(flight: SimulatedFlight) -> None:
    msgs = list(flight.messages())
    nav = TerrainNavigator(flight.world.ref_map, PAPER)
    _feed(nav, msgs[:900])
    assert nav.N_valid > 0
    t = msgs[899].header.stamp_ns * 1e-9
    out = nav.step(NavReset(header=_hdr(t), reason="INS reset by operator"))
    assert len(out) == 1 and isinstance(out[0], TerrainVerdict) and out[0].state == "RESET"
    assert out[0].detail == "INS reset by operator"
    assert nav.N_valid == 0 and nav.total_meas == 0 and not nav.window.measq and not nav.search.group
    assert np.all(nav.bank.x == 0) and np.array_equal(nav.bank.P, nav.bank.P0) and not nav.search.argmin_hist
    out, _ = _feed(nav, msgs[900:])
    verdicts = [m for m in out if isinstance(m, TerrainVerdict)]
    assert verdicts[0].n_measurements == 4 and verdicts[0].n_valid == 3  # first residual excluded again


def test_long_gap_resets_the_window(flight: SimulatedFlight) -> None:
    # a 30 s dropout is longer than T_reset = N_max cells (40 s at 200 m/s)? No: 30 s < 40 s, keep the window;
    # 45 s > 40 s resets it (on a 400-cell map so that the flight continues afterwards)
    results = {}
    for dur in (30.0, 45.0):
        sc = SC.model_copy(
            update={"map_cells": (400, 101), "failures": (FailureSpec(kind="dropout", onset_s=30.0, duration_s=dur),)}
        )
        fl = simulate(sc, 8)
        nav = TerrainNavigator(fl.world.ref_map, PAPER)
        _feed(nav, list(fl.messages()))
        results[dur] = nav.counters["window_resets"]
    assert results == {30.0: 0, 45.0: 1}


# --- AT-11: grouping invariance (§2.9 S2) ---------------------------------------------------------------------


def _cell_measurements(fl: SimulatedFlight, n: int) -> list[CellMeasurement]:
    ref = fl.world.ref_map
    rs = CellResampler(ref.x0_m, ref.z0_m, ref.cell_m, ref.zone_mask(25, 25))
    out = []
    for k in range(fl.tau.size):
        m, _ = rs.push(
            float(fl.t[k]), float(fl.x_ins[k]), float(fl.z_ins[k]), float(fl.h_ins[k]), float(fl.h_ra[k]), True, 200.0
        )
        if m is not None:
            out.append(m)
    # lengthen to n measurements by replaying the stream shifted in time (a 2nd pass over the same cells)
    period = out[-1].t - out[0].t + 0.625
    k = 0
    while len(out) < n:
        out.append(dataclasses.replace(out[k], t=out[k].t + period))
        k += 1
    return out[:n]


def test_at11_grouping_gives_identical_states_and_f(flight: SimulatedFlight) -> None:
    meas = _cell_measurements(flight, 128)
    ref = flight.world.ref_map
    nav1 = TerrainNavigator(ref, TerrainNavConfig(preset="paper", N_p=1))
    snaps = []
    for m in meas:
        nav1.search.push_measurement(dataclasses.replace(m))  # type: ignore[attr-defined]
        snaps.append((nav1.bank.x.copy(), nav1.F.copy(), nav1.N_valid))
    assert nav1.n_evaluations == 128
    for N_p in (2, 4, 8):
        nav = TerrainNavigator(ref, TerrainNavConfig(preset="paper", N_p=N_p))
        evaluated_at = []
        for k, m in enumerate(meas):
            if nav.search.push_measurement(dataclasses.replace(m)):  # type: ignore[attr-defined]
                evaluated_at.append(k + 1)
                S1, F1, n1 = snaps[k]
                np.testing.assert_allclose(nav.bank.x, S1, rtol=0, atol=1e-12 * np.abs(S1).max())
                np.testing.assert_allclose(nav.F, F1, rtol=0, atol=1e-12 * np.abs(F1).max())
                assert nav.N_valid == n1
                assert np.array_equal(nav.bank.x, S1) and np.array_equal(nav.F, F1)  # in fact bit-identical
        assert evaluated_at == list(range(N_p, 129, N_p))  # checks run exactly every N_p measurements


# --- AT-14: window memory (§2.9 S3) -------------------------------------------------------------------------------


def test_at14_window_stores_at_most_ceil_nmax_over_ns_plus_two_arrays(flight: SimulatedFlight) -> None:
    cfg = PAPER
    nav = TerrainNavigator(flight.world.ref_map, cfg)
    base = BaseRecurrentSearch(flight.world.ref_map, cfg)
    most = 0
    most_base = 0
    for msg in flight.messages():
        nav.step(msg)
        base.step(msg)
        most = max(most, nav.window.stored_arrays())
        most_base = max(most_base, len(base.window.segq))
    assert most <= math.ceil(cfg.N_max / cfg.N_s) + 2
    # the base algorithm stores one array per sample: N_max cells of profile = ceil(64 * 12.5) = 800 samples
    assert most_base == math.ceil(64 * 20.0 * 125.0 / 200.0)
    assert most_base / most >= cfg.N_s


# --- options ---------------------------------------------------------------------------------------------------------


def test_baro_altitude_source_uses_the_baro_stream(flight: SimulatedFlight) -> None:
    msgs = list(flight.messages())
    with_baro: list[Message] = []
    for m in msgs:
        with_baro.append(m)
        if isinstance(m, InsSample):  # a baro altitude equal to the INS one, 0.0 s later
            with_baro.append(BaroAltitude(header=m.header, h_baro_m=m.h_m))
    ins_run, _ = _feed(TerrainNavigator(flight.world.ref_map, PAPER), msgs)
    baro_cfg = TerrainNavConfig(preset="paper", altitude_source="baro")
    baro_run, rejected = _feed(TerrainNavigator(flight.world.ref_map, baro_cfg), with_baro)
    assert not rejected
    fa = [m for m in ins_run if isinstance(m, TerrainFix)]
    fb = [m for m in baro_run if isinstance(m, TerrainFix)]
    assert len(fa) == len(fb) > 0
    for a, b in zip(fa, fb, strict=True):
        assert (a.dx_m, a.dz_m) == pytest.approx((b.dx_m, b.dz_m), abs=1e-6)
        dh = a.vertical.index("dh")
        assert a.vertical.mean[dh] == pytest.approx(b.vertical.mean[dh], abs=1e-6)
    # without the baro stream every RA sample is unsynchronisable
    _, rejected = _feed(TerrainNavigator(flight.world.ref_map, baro_cfg), msgs[:100])
    assert rejected == Counter({"unsynchronised": 50})


def test_pre_gate_is_off_by_default_and_gates_spikes_when_on() -> None:
    sc = SC.model_copy(
        update={"failures": (FailureSpec(kind="additive", onset_s=20.0, duration_s=3.0, amplitude_m=150.0),)}
    )
    fl = simulate(sc, 4)
    off = run_flight(fl, PAPER)
    assert off.navigator.counters["gated"] == 0
    on = run_flight(fl, TerrainNavConfig(preset="paper", pre_gate_k=4.0))
    assert 3 <= on.navigator.counters["gated"] <= 6  # the ~5 cells crossed during the 3 s spike


def test_refinement_flags_fixes_and_keeps_them_accurate(flight: SimulatedFlight) -> None:
    res = run_flight(flight, TerrainNavConfig(preset="paper", refine=True))
    fixes = res.fixes
    assert fixes and all(f.refined for f in fixes)
    errs = np.array([fix_errors_cells(f, flight) for f in fixes])
    assert np.abs(errs).max() <= 1.0
    for f in fixes:
        assert np.all(np.linalg.eigvalsh(np.array(f.estimate.covariance)) > 0)


def test_refinement_beats_the_cell_centre_estimate() -> None:
    # the grid estimate's error is spread over +-1/2 cell per flight (rms ~0.3 cell, the sub-cell position of
    # the true track); pooled over 6 flights the sub-cell search must do clearly better
    plain, refined = [], []
    for seed in range(20, 26):
        fl = simulate(SC, seed)
        plain += [fix_errors_cells(f, fl) for f in run_flight(fl, PAPER).fixes]
        refined += [
            fix_errors_cells(f, fl) for f in run_flight(fl, TerrainNavConfig(preset="paper", refine=True)).fixes
        ]
    rms = [float(np.sqrt(np.mean(np.square(e)))) for e in (plain, refined)]
    assert rms[1] < 0.6 * rms[0], rms


def test_derived_n_limits_follow_the_recipe(flight: SimulatedFlight) -> None:
    cfg = TerrainNavConfig(preset="paper", derive_profiles=60)
    N_min, N_max = derive_n_limits(flight.world.ref_map, cfg, n_cap=48)
    assert 8 <= N_min <= 40
    assert N_max == min(4 * N_min, math.floor(200.0 / (4 * 0.3)))
    assert n_max_from(10, cfg) == 40 and n_max_from(50, cfg) == 166
    nav = TerrainNavigator(
        flight.world.ref_map, TerrainNavConfig(preset="paper", derive_n_limits=True, derive_profiles=40)
    )
    assert 8 <= nav.N_min <= 64 and nav.N_max == n_max_from(nav.N_min, cfg)
    flat = simulate(SC.model_copy(update={"terrain": "flat"}), 1)
    with pytest.raises(ValueError, match="not informative"):
        derive_n_limits(flat.world.ref_map, cfg, n_cap=24)


# --- synchronisation (§5.1) -----------------------------------------------------------------------------------------


def test_ra_is_synchronised_by_linear_interpolation_of_the_bracketing_ins() -> None:
    sync = Synchroniser(0.2)
    assert sync.add_ins(10.0, 1000.0, 50.0, 900.0, 200.0, 0.0, 1.0)[0] == []
    assert sync.add_ra(10.08, 300.0) == []  # waits for the INS sample after it
    out, gap = sync.add_ins(10.1, 1020.0, 51.0, 901.0, 200.0, 0.0, 3.0)
    assert not gap and len(out) == 1
    s = out[0]
    assert (s.t, s.x, s.z, s.h_ins, s.h_ra) == pytest.approx((10.08, 1016.0, 50.8, 900.8, 300.0))
    assert s.v_ground == pytest.approx(200.0) and s.vh == pytest.approx(2.6)
    assert sync.would_drop(10.31) and not sync.would_drop(10.29)
    assert sync.would_drop(9.9)  # older than the INS samples kept


def test_scoring_from_truth_messages_matches_scoring_from_the_flight(flight: SimulatedFlight) -> None:
    from schemas import Truth
    from services.terrain_nav.metrics import TruthTrack, score_run

    msgs = list(flight.messages(include_truth=True, truth_every=1))
    truths = [m for m in msgs if isinstance(m, Truth)]
    outputs, _ = _feed(TerrainNavigator(flight.world.ref_map, PAPER), msgs)
    a = score_run(outputs, flight)
    b = score_run(outputs, TruthTrack(truths, 125.0))
    assert a["n_fixes"] == b["n_fixes"] > 0
    np.testing.assert_allclose(a["errors_cells"], b["errors_cells"], atol=1e-9)
    np.testing.assert_allclose(a["vertical_abs_error_m"], b["vertical_abs_error_m"], atol=1e-6)


@pytest.mark.parametrize("name", ["paper_replica", "flat", "dropouts", "out_of_zone", "ins_gap"])
def test_named_scenarios_simulate_and_run(name: str) -> None:
    from services.terrain_nav.scenarios import SCENARIOS

    sc = SCENARIOS[name]
    fl = simulate(sc, 1)
    res = run_flight(fl, PAPER)
    assert res.verdicts and set(res.rejected) <= {"ra_invalid", "non_finite", "unsynchronised"}
    for f in res.fixes:
        assert max(abs(e) for e in fix_errors_cells(f, fl)) <= 1.5
