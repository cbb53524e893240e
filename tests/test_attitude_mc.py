"""Monte-Carlo acceptance of the attitude estimator: digest 004 §4.2 (P1-P6), §4.3 (regression tables, all three
radars), §4.4 (consistency C1, C2), on the §3.1 scenario, through the same core class the service uses.

Sizes. The digest's figures come from N = 3074 runs (U14); the ``slow`` variants use exactly that N and the
digest's tolerances. The default run uses N = 300 (sigma_j = 0.03) and N = 200 (sigma_j = 0: C1 and P6).

Tolerance widening for smaller N (stated once, used everywhere below). The relative standard error of an RMS
estimated from N runs of ~Gaussian errors is SE_N = 1 / sqrt(2 N): 1.3 % at N = 3074 (the digest's own
Monte-Carlo noise, already inside its tolerances), 4.1 % at N = 300, 5.0 % at N = 200. A tolerance stated for
N = 3074 is widened by z (SE_N - SE_3074) with z = 3.3, i.e. a per-comparison false-alarm rate of ~1e-3, small
enough for the ~150 comparisons of the default run (errors of one run are correlated across scans and angles,
so the comparisons are far from independent). At N = 3074 the widening is zero: the slow tests apply the digest's
tolerances unchanged. Ratios under common random numbers (P6) are much less noisy than that; the same widening
is applied to them and is conservative. Seeds are fixed, so every run is deterministic.
"""

from __future__ import annotations

import itertools
import json
import math
import os
from functools import cache
from typing import Any

import pytest

from services.attitude.config import MeasurementSigmas
from services.attitude.offline import evaluation_config, monte_carlo_size, run_monte_carlo
from services.attitude.simulation import paper_plan

RADARS = ("9S15", "Vostok3D", "19Zh6")
LOS = ("psi_los", "theta_los", "gamma_los")
N_FULL = monte_carlo_size()  # 3074
N_DEFAULT = 300
N_ZERO_JERK = 200
SEED = 2024
Z = 3.3


def widening(n: int) -> float:
    """z (SE_N - SE_3074): the extra relative tolerance for N runs instead of the digest's 3074."""
    return Z * (1.0 / math.sqrt(2 * n) - 1.0 / math.sqrt(2 * N_FULL))


@cache
def mc(radar: str, sigma_j: float, n: int, variant: str = "paper", n_scans: int = 100) -> dict[str, Any]:
    """One Monte-Carlo set (cached for the module): ``n`` runs of the §3.1 scenario through one core."""
    sig = MeasurementSigmas.preset(radar)  # type: ignore[arg-type]
    plan = paper_plan()
    if variant == "double_angles":
        sig = MeasurementSigmas(
            sigma_r_m=sig.sigma_r_m, sigma_az_deg=2 * sig.sigma_az_deg, sigma_el_deg=2 * sig.sigma_el_deg
        )
    elif variant == "double_range":
        sig = MeasurementSigmas(
            sigma_r_m=2 * sig.sigma_r_m, sigma_az_deg=sig.sigma_az_deg, sigma_el_deg=sig.sigma_el_deg
        )
    elif variant == "half_range":
        plan = paper_plan(r0_m=50e3)
    cfg = evaluation_config(None, sigmas=sig, sigma_jerk_mps3=sigma_j)
    res = run_monte_carlo(cfg, n, plan=plan, n_scans=n_scans, seed=SEED)
    dump = os.environ.get("ATTITUDE_MC_DUMP")  # optional: keep the figures for docs/attitude.md
    if dump:
        with open(f"{dump}/{radar}_{sigma_j}_{n}_{variant}_{n_scans}.json", "w") as f:
            json.dump(res, f)
    return res


def at(res: dict[str, Any], key: str, angle: str, scan: int) -> float:
    return float(res[key][angle][scan - 1])


SIZES = [pytest.param(N_DEFAULT, id="N300"), pytest.param(N_FULL, id="N3074", marks=pytest.mark.slow)]
SIZES_ZERO = [pytest.param(N_ZERO_JERK, id="N200"), pytest.param(N_FULL, id="N3074", marks=pytest.mark.slow)]

# §4.3 regression targets, sigma_j = 0.03: scans 11, 21, 41, 61, 100 and raw @ 41 (deg)
REGRESSION = {
    "9S15": {
        "psi_los": (11.1, 4.19, 2.71, 2.25, 1.93, 51.2),
        "theta_los": (9.91, 3.81, 2.56, 2.17, 1.71, 33.2),
        "gamma_los": (9.19, 2.18, 1.65, 1.65, 1.76, 53.4),
    },
    "Vostok3D": {
        "psi_los": (14.9, 5.76, 3.03, 2.12, 0.62, 51.7),
        "theta_los": (3.35, 1.59, 1.43, 1.22, 0.97, 12.5),
        "gamma_los": (10.0, 2.12, 1.23, 1.07, 0.98, 58.5),
    },
    "19Zh6": {
        "psi_los": (12.6, 4.77, 2.92, 2.42, 2.04, 56.8),
        "theta_los": (27.5, 12.2, 5.04, 4.27, 3.18, 55.3),
        "gamma_los": (22.4, 5.48, 2.77, 2.97, 3.21, 57.0),
    },
}
REG_SCANS = (11, 21, 41, 61, 100)
# §4.3 additional targets at scan 41: earth psi, theta, gamma, gamma_los_euler, aspect az, el (deg), pos (m), vel (m/s)
EXTRA_41 = {
    "9S15": (2.56, 2.44, 1.12, 1.29, 2.64, 2.26, 322.0, 14.5),
    "Vostok3D": (2.81, 1.37, 1.11, 1.29, 2.96, 1.32, 311.0, 12.7),
    "19Zh6": (2.76, 4.69, 1.16, 1.35, 2.86, 4.38, 626.0, 20.7),
}
# §4.3 first scan at which the RMS drops below 5 / 3 deg (None: never within 100 scans)
FIRST_BELOW = {
    "9S15": {"psi_los": (19, 28), "theta_los": (18, 26), "gamma_los": (15, 18)},
    "Vostok3D": {"psi_los": (23, 43), "theta_los": (9, 12), "gamma_los": (15, 19)},
    "19Zh6": {"psi_los": (21, 33), "theta_los": (42, None), "gamma_los": (23, 34)},
}
# §4.4 reference RMS for C1 (sigma_j = 0): scans 21, 41, 61, 100
C1_REFERENCE = {
    "9S15": {
        "psi_los": (4.16, 1.38, 0.69, 0.25),
        "theta_los": (3.79, 1.31, 0.64, 0.19),
        "gamma_los": (2.13, 0.69, 0.41, 0.20),
    },
    "Vostok3D": {
        "psi_los": (4.96, 1.15, 0.36, 0.06),
        "theta_los": (1.27, 0.44, 0.21, 0.06),
        "gamma_los": (1.81, 0.29, 0.14, 0.07),
    },
    "19Zh6": {
        "psi_los": (4.75, 1.58, 0.79, 0.29),
        "theta_los": (12.2, 4.36, 2.12, 0.62),
        "gamma_los": (5.45, 2.20, 1.34, 0.66),
    },
}


# ----------------------------------------------------------------------------------------------------- §4.2
@pytest.mark.parametrize("n", SIZES)
def test_p1_filtering_is_much_better_than_raw(n: int) -> None:
    # digest: >= 4x at scan 41 (observed >= 8.7x for sigma_j <= 0.03); MC noise of the ratio ~SE_N, margin > 50 %
    for radar in RADARS:
        res = mc(radar, 0.03, n)
        for a in LOS:
            assert at(res, "raw_rms", a, 41) >= 4.0 * at(res, "rms", a, 41), (radar, a)


@pytest.mark.parametrize("n", SIZES)
def test_p2_raw_angles_are_very_poor(n: int) -> None:
    floor = {"psi_los": 30.0, "gamma_los": 20.0, "theta_los": 10.0}
    for radar in RADARS:
        res = mc(radar, 0.03, n)
        for a, thr in floor.items():
            worst = min(res["raw_rms"][a][2:100])  # scans 3..100
            assert worst > thr * (1.0 - widening(n)), (radar, a, worst)


@pytest.mark.parametrize("n", SIZES)
def test_p3_transient_at_first_contacts(n: int) -> None:
    for radar in RADARS:
        res = mc(radar, 0.03, n)
        # at scan 3 the KF estimate is the FSF estimate, which is the raw 3-point estimate: identical statistics
        for a in LOS:
            assert at(res, "rms", a, 3) == pytest.approx(at(res, "raw_rms", a, 3), rel=1e-9, abs=1e-9)
            assert at(res, "mean", a, 3) == pytest.approx(at(res, "raw_mean", a, 3), rel=1e-9, abs=1e-9)
        # "RMS psi_los ~ 56-61 deg" at scan 3: "~" read as +-5 %, widened for N
        w = 0.05 + widening(n)
        assert 56.0 * (1 - w) <= at(res, "rms", "psi_los", 3) <= 61.0 * (1 + w), radar
        assert at(res, "rms", "psi_los", 11) > 9.0 * (1 - widening(n)), radar


@pytest.mark.parametrize("n", SIZES)
def test_p4_accuracy_improves_with_time(n: int) -> None:
    for radar in RADARS:
        rms = [at(mc(radar, 0.03, n), "rms", "psi_los", k) for k in (3, 11, 21, 41, 100)]
        for prev, nxt in itertools.pairwise(rms):
            assert nxt <= 1.10 * prev, (radar, rms)


@pytest.mark.parametrize("n", SIZES)
def test_p5_units_of_degrees_after_about_40_contacts(n: int) -> None:
    for radar in RADARS:
        res = mc(radar, 0.03, n)
        for a in LOS:
            assert 0.2 <= at(res, "rms", a, 41) <= 10.0, (radar, a)
        for k in range(3, 11):
            assert max(at(res, "rms", a, k) for a in LOS) > 10.0, (radar, k)


@pytest.mark.parametrize("n", SIZES_ZERO)
def test_p6_range_and_angle_accuracy_dominate(n: int) -> None:
    """sigma_j = 0, 9S15, scan 41, common random numbers across the four sets."""
    base = mc("9S15", 0.0, n)
    w = widening(n)
    for variant, lo, hi in (("double_angles", 1.9, 2.05), ("double_range", 0.9, 1.1), ("half_range", 0.35, 0.65)):
        other = mc("9S15", 0.0, n, variant, n_scans=41)
        for a in LOS:
            ratio = at(other, "rms", a, 41) / at(base, "rms", a, 41)
            assert lo * (1 - w) <= ratio <= hi * (1 + w), (variant, a, ratio)


# ----------------------------------------------------------------------------------------------------- §4.3
@pytest.mark.parametrize("radar", RADARS)
@pytest.mark.parametrize("n", SIZES)
def test_regression_table_los_rms(n: int, radar: str) -> None:
    res = mc(radar, 0.03, n)
    w = widening(n)
    for a in LOS:
        ref = REGRESSION[radar][a]
        for scan, expected in zip(REG_SCANS, ref[:5], strict=True):
            tol = (0.25 if scan == 11 else 0.15) + w
            got = at(res, "rms", a, scan)
            assert abs(got / expected - 1.0) <= tol, (radar, a, scan, got, expected)
        got = at(res, "raw_rms", a, 41)
        assert abs(got / ref[5] - 1.0) <= 0.15 + w, (radar, a, "raw", got, ref[5])


@pytest.mark.parametrize("radar", RADARS)
@pytest.mark.parametrize("n", SIZES)
def test_regression_additional_targets_at_scan_41(n: int, radar: str) -> None:
    res = mc(radar, 0.03, n)
    tol = 0.15 + widening(n)
    names = ("psi", "theta", "gamma", "gamma_los_euler", "aspect_az", "aspect_el")
    exp = EXTRA_41[radar]
    for name, expected in zip(names, exp[:6], strict=True):
        got = at(res, "rms", name, 41)
        assert abs(got / expected - 1.0) <= tol, (radar, name, got, expected)
    assert abs(res["pos_rms_m"][40] / exp[6] - 1.0) <= tol
    assert abs(res["vel_rms_mps"][40] / exp[7] - 1.0) <= tol


@pytest.mark.parametrize("n", SIZES)
def test_regression_mean_error_at_scan_41(n: int) -> None:
    # digest: |mean| < 0.3 deg at N = 3074; the standard error of a mean is RMS / sqrt(N)
    for radar in RADARS:
        res = mc(radar, 0.03, n)
        for a in LOS:
            rms = at(res, "rms", a, 41)
            bound = 0.3 + Z * (rms / math.sqrt(n) - rms / math.sqrt(N_FULL))
            assert abs(at(res, "mean", a, 41)) < bound, (radar, a)


@pytest.mark.parametrize("radar", RADARS)
@pytest.mark.parametrize("n", SIZES)
def test_regression_first_scan_below_5_and_3_deg(n: int, radar: str) -> None:
    """At the digest's first scan the RMS is below the threshold, one scan earlier it is not, both within the
    regression tolerance (a crossing scan of a slowly falling curve is only as exact as the curve)."""
    res = mc(radar, 0.03, n)
    tol = 0.15 + widening(n)
    for a in LOS:
        for thr, first in zip((5.0, 3.0), FIRST_BELOW[radar][a], strict=True):
            rms = res["rms"][a]
            if first is None:
                assert min(rms[20:100]) > thr / (1 + tol), (radar, a, thr)
                continue
            assert rms[first - 1] < thr * (1 + tol), (radar, a, thr, first)
            assert rms[first - 2] > thr / (1 + tol), (radar, a, thr, first)


# ----------------------------------------------------------------------------------------------------- §4.4
@pytest.mark.parametrize("radar", RADARS)
@pytest.mark.parametrize("n", SIZES_ZERO)
def test_c1_predicted_sigma_matches_rms_when_model_matches(n: int, radar: str) -> None:
    res = mc(radar, 0.0, n)
    w = widening(n)
    for a in LOS:
        cons = res["consistency"][a]
        assert cons["scans"] == [21, 100]
        assert all(abs(r - 1.0) <= 0.15 + w for r in cons["ratio"]), (radar, a, min(cons["ratio"]), max(cons["ratio"]))
        assert abs(cons["mean_ratio"] - 1.0) <= 0.15, (radar, a)
        for scan, expected in zip((21, 41, 61, 100), C1_REFERENCE[radar][a], strict=True):
            got = at(res, "rms", a, scan)
            assert abs(got / expected - 1.0) <= 0.15 + w, (radar, a, scan, got, expected)


@pytest.mark.parametrize("radar", RADARS)
@pytest.mark.parametrize("n", SIZES)
def test_c2_filter_is_conservative_with_jerk_noise(n: int, radar: str) -> None:
    res = mc(radar, 0.03, n)
    for a in LOS:
        cons = res["consistency"][a]
        assert min(cons["ratio"]) >= 0.95 * (1 - widening(n)), (radar, a, min(cons["ratio"]))
        assert cons["mean_ratio"] >= 0.95, (radar, a)


@pytest.mark.parametrize("n", SIZES)
def test_reported_angles_are_defined_from_scan_3_and_gating_is_rare(n: int) -> None:
    for radar in RADARS:
        res = mc(radar, 0.03, n)
        assert res["defined_fraction"]["psi_los"][:2] == [0.0, 0.0]  # INIT: no angles
        plots = n * 98
        # chi2(3) gate at 99.99 %: expect 1e-4 of the updates; allow 5x for heavy tails of the early transient
        assert res["rejected"].get("innovation_gate", 0) <= 5e-4 * plots + 3
        frac = res["defined_fraction"]["gamma_los"][2:]
        assert min(frac) >= 1.0 - (res["rejected"].get("innovation_gate", 0) + 1) / n
