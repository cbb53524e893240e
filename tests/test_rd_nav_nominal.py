"""Digest 002 §6.3 (T-NOM-1..8): PF accuracy and consistency in the REF and LOW scenarios.

Default run: fewer and shorter runs than the digest's (100 x 4 h), so that the whole rd_nav set stays
within about two minutes on one core; the full-size versions are behind ``@pytest.mark.slow``.

Why the digest's limits still hold for the short runs (Monte-Carlo standard errors): the errors of
successive 10 s cycles are nearly independent (each cycle re-fixes the position: the per-cycle DR
uncertainty q = 1.35 m exceeds the single-cycle CRLB, §4.6), so n cycles estimate a per-axis SD with a
relative standard error of about 1/sqrt(2 n_eff), n_eff ~ n/2. With >= 700 cycles per case that is <= 4 %,
i.e. SD 0.45 +- 0.02 m against the limit 0.75 m, mean 0 +- 0.03 m against 0.25 m, RMS 0.57 +- 0.02 m
against 0.70 m. A p99 from ~1400 samples has about +-8 % error (1.30 +- 0.1 m against 1.6 m). The
maximum of fewer samples is smaller on average, so the max limits are not easier to fail than with 100
runs; they are kept as in the digest. Where a limit is closer than ~4 standard errors to the
expected value the default test widens it and says so.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from services.rd_nav.config import RdNavConfig
from services.rd_nav.offline import RunLog, monte_carlo
from services.rd_nav.simulation import low, ref

MC = {"propagated_fix_period_s": 0.0, "emit_propagated_after_cycle": False}
LOW_CORE = {"sigma_t_s": 0.1e-3}  # the filter knows LOW's timing noise (sigma_c comes from SoundSpeed)
BOUNDARY_LAP_S = 6000.0  # one lap of the 8.8 km triangle at 1.5 m/s is 5867 s
OUTSIDE_PATTERN_S = 7600.0  # one pass over the whole lawnmower


def mc(scn: Any, runs: int, seed0: int, **core: Any) -> tuple[dict[str, Any], list[RunLog]]:
    return monte_carlo(scn, runs, seed0, RdNavConfig(**MC, **core))


# ------------------------------------------------------------------ default-size Monte-Carlo sets ----
@pytest.fixture(scope="module")
def ref_inside() -> tuple[dict[str, Any], list[RunLog]]:
    return mc(ref("inside", duration_s=3600.0), 4, 1000)


@pytest.fixture(scope="module")
def ref_boundary() -> tuple[dict[str, Any], list[RunLog]]:
    return mc(ref("boundary", duration_s=BOUNDARY_LAP_S), 2, 2000)


@pytest.fixture(scope="module")
def ref_outside() -> tuple[dict[str, Any], list[RunLog]]:
    return mc(ref("outside", duration_s=OUTSIDE_PATTERN_S), 1, 3000)


def check_envelope(
    p: dict[str, Any], mean: float, sd: tuple[float, float], rms: float, p99: float | None, mx: float
) -> None:
    assert abs(p["mean_x_m"]) <= mean and abs(p["mean_y_m"]) <= mean, p
    assert p["sd_x_m"] <= sd[0] and p["sd_y_m"] <= sd[1], p
    assert p["rms_m"] <= rms, p
    if p99 is not None:
        assert p["p99_m"] <= p99, p
    assert p["max_m"] <= mx, p


def test_t_nom_1_ref_inside(ref_inside: tuple[dict[str, Any], list[RunLog]]) -> None:
    """T-NOM-1: |mean| <= 0.25, SD <= 0.75, RMS <= 0.70, p99 <= 1.6, max <= 3.0 m (4 x 1 h, 1440 cycles)."""
    agg, _ = ref_inside
    check_envelope(agg["pf"], 0.25, (0.75, 0.75), 0.70, 1.6, 3.0)


def test_t_nom_2_ref_boundary(ref_boundary: tuple[dict[str, Any], list[RunLog]]) -> None:
    """T-NOM-2: |mean| <= 0.25, SD <= 0.75, RMS <= 0.80, p99 <= 2.0, max <= 4.0 m (2 laps, 1200 cycles)."""
    agg, _ = ref_boundary
    check_envelope(agg["pf"], 0.25, (0.75, 0.75), 0.80, 2.0, 4.0)


def test_t_nom_3_ref_outside(ref_outside: tuple[dict[str, Any], list[RunLog]]) -> None:
    """T-NOM-3: |mean| <= 0.25, SD x <= 1.3 / y <= 0.6, RMS <= 1.4, p99 <= 3.8, max <= 8.0 m (one full pass).

    760 cycles: the x SD (1.05 expected) has a standard error of ~0.04 m, far from 1.3.
    """
    agg, _ = ref_outside
    check_envelope(agg["pf"], 0.25, (1.3, 0.6), 1.4, 3.8, 8.0)


@pytest.mark.parametrize(
    ("path", "dur", "rms", "mx"), [("inside", 3600.0, 0.5, 2.0), ("boundary", BOUNDARY_LAP_S, 0.5, 2.0)]
)
def test_t_nom_4_low_paper_envelope(path: str, dur: float, rms: float, mx: float) -> None:
    """T-NOM-4: LOW inside and boundary meet the complete paper envelope: |mean| <= 0.25, SD <= 0.75,
    RMS <= 0.5, max <= 2.0 m (one run each by default)."""
    agg, _ = mc(low(path, duration_s=dur), 1, 4000 if path == "inside" else 4100, **LOW_CORE)
    check_envelope(agg["pf"], 0.25, (0.75, 0.75), rms, None, mx)


def test_t_nom_4b_low_outside() -> None:
    """T-NOM-4b: LOW outside: |mean| <= 0.25, SD <= 0.75, RMS <= 0.9, p99 <= 2.5, max <= 5.0 m."""
    agg, _ = mc(low("outside", duration_s=OUTSIDE_PATTERN_S), 1, 4200, **LOW_CORE)
    check_envelope(agg["pf"], 0.25, (0.75, 0.75), 0.9, 2.5, 5.0)


def test_t_nom_5_consistency(ref_inside: Any, ref_boundary: Any, ref_outside: Any) -> None:
    """T-NOM-5: RMS(|e|) / RMS(sqrt(trace Q_k)) in [0.8, 1.25] for the three REF cases.

    The ratio's standard error over >= 760 cycles is ~3 % (RMS of |e| ~ 2.5 %, the trace is smooth).
    """
    for agg, _ in (ref_inside, ref_boundary, ref_outside):
        assert 0.8 <= agg["pf"]["consistency"] <= 1.25, agg["pf"]


def test_t_nom_6_ekf_shadow_matches_pf(ref_inside: Any, ref_boundary: Any, ref_outside: Any) -> None:
    """T-NOM-6: EKF RMS within +-5 % of the PF RMS; EKF mean NEES in [1.5, 3.0].

    PF and EKF see the same data, so their RMS difference has little Monte-Carlo noise (paired).
    """
    for agg, _ in (ref_inside, ref_boundary, ref_outside):
        pf, ekf = agg["pf"], agg["ekf"]
        assert abs(ekf["rms_m"] / pf["rms_m"] - 1.0) <= 0.05, (pf["rms_m"], ekf["rms_m"])
        assert 3.0 >= ekf["mean_nees"] >= 1.5, ekf["mean_nees"]


def test_t_nom_7_particle_count(ref_inside: tuple[dict[str, Any], list[RunLog]]) -> None:
    """T-NOM-7: with N = 300 the RMS is within +5 % of N = 1000 (paired: the same simulated data)."""
    agg300, _ = mc(ref("inside", duration_s=3600.0), 2, 1000, n_particles=300)
    runs1000 = [lg.metrics("auv4")["pf"] for lg in ref_inside[1][:2]]
    rms1000 = float(np.sqrt(sum(r["sum_e2"] for r in runs1000) / sum(r["n"] for r in runs1000)))
    assert agg300["pf"]["rms_m"] <= 1.05 * rms1000, (agg300["pf"]["rms_m"], rms1000)


def test_t_nom_8_visual_zone_and_no_reinit_in_nominal_runs(
    ref_inside: Any, ref_boundary: Any, ref_outside: Any
) -> None:
    """T-NOM-8: |e| < 10 m always (the ~10 m visual-navigation zone); nominal runs never re-initialise (T-ROB-8)."""
    for agg, _ in (ref_inside, ref_boundary, ref_outside):
        assert agg["pf"]["max_m"] < 10.0
        assert agg["reinit_total"] == 0
        assert agg["rejected_cycles"].get("NIS_GATE", 0) <= 2


# ------------------------------------------------------------------------------ full size (slow) ----
@pytest.mark.slow
@pytest.mark.parametrize(
    ("path", "mean", "sd", "rms", "p99", "mx"),
    [
        ("inside", 0.25, (0.75, 0.75), 0.70, 1.6, 3.0),
        ("boundary", 0.25, (0.75, 0.75), 0.80, 2.0, 4.0),
        ("outside", 0.25, (1.3, 0.6), 1.4, 3.8, 8.0),
    ],
)
def test_t_nom_1_2_3_5_6_8_full(
    path: str, mean: float, sd: tuple[float, float], rms: float, p99: float, mx: float
) -> None:
    """T-NOM-1/2/3 with 100 runs of 4 h, and T-NOM-5, -6, -8 on the same runs."""
    agg, _ = mc(ref(path), 100, 10_000)
    check_envelope(agg["pf"], mean, sd, rms, p99, mx)
    assert 0.8 <= agg["pf"]["consistency"] <= 1.25
    assert abs(agg["ekf"]["rms_m"] / agg["pf"]["rms_m"] - 1.0) <= 0.05
    assert 3.0 >= agg["ekf"]["mean_nees"] >= 1.5
    assert agg["pf"]["max_m"] < 10.0 and agg["reinit_total"] == 0


@pytest.mark.slow
@pytest.mark.parametrize("path", ["inside", "boundary"])
def test_t_nom_4_full(path: str) -> None:
    agg, _ = mc(low(path), 30, 11_000, **LOW_CORE)
    check_envelope(agg["pf"], 0.25, (0.75, 0.75), 0.5, None, 2.0)


@pytest.mark.slow
def test_t_nom_4b_full() -> None:
    agg, _ = mc(low("outside"), 30, 12_000, **LOW_CORE)
    check_envelope(agg["pf"], 0.25, (0.75, 0.75), 0.9, 2.5, 5.0)


@pytest.mark.slow
def test_t_nom_7_full() -> None:
    a300, _ = mc(ref("inside"), 30, 13_000, n_particles=300)
    a1000, _ = mc(ref("inside"), 30, 13_000)
    assert a300["pf"]["rms_m"] <= 1.05 * a1000["pf"]["rms_m"]
