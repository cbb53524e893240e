"""The nav_platform error models have the configured statistics (sensor_stats against normal theory).

One long run (10 000 s, 1 Hz sensors, circling so the heading wraps through north many times). Every
check has a two-sided false-alarm probability of ALPHA = 1e-6, computed from the sample size:

* white noise: (N - 1) s^2 / sigma^2 ~ chi-square(N - 1); |mean - bias| <= z sigma / sqrt(N);
* correlated (Gauss-Markov) errors: large-sample normal theory with the autocovariance c(k):
  Var(mean) = sum_k c(k) / N, Var(s^2) = 2 sum_k c(k)^2 / N (sums over all lags k).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from scipy.stats import chi2, norm
from test_scenario_files import nav_scenario

from services.player.scenario import parse_scenario
from services.player.sensor_stats import error_series, sensor_stats
from services.player.timeline import build, player_source, stamp
from shared import keys

ALPHA = 1e-6
Z = float(norm.ppf(1 - ALPHA / 2))
DURATION_S = 10_000.0
RATE_HZ = 1.0
N = int(DURATION_S * RATE_HZ) + 1
TAU_S = 5.0
A = math.exp(-1.0 / (TAU_S * RATE_HZ))  # lag-1 autocorrelation of the Gauss-Markov process

SENSORS: list[dict[str, Any]] = [
    {"type": "dvl", "id": "dvl0", "rate_hz": RATE_HZ, "sigma_mps": 0.05, "bias_mps": [0.02, -0.01, 0.005]},
    {"type": "speed_log", "id": "log0", "rate_hz": RATE_HZ, "sigma_mps": 0.1},
    {"type": "heading", "id": "gm", "rate_hz": RATE_HZ, "gm_sigma_deg": 2.0, "gm_tau_s": TAU_S},
    {
        "type": "heading",
        "id": "full",
        "rate_hz": RATE_HZ,
        "bias_deg": 0.5,
        "gm_sigma_deg": 1.0,
        "gm_tau_s": TAU_S,
        "white_sigma_deg": 0.5,
    },
    {"type": "depth", "id": "press0", "rate_hz": RATE_HZ, "sigma_m": 0.1, "bias_m": 0.05},
    {
        "type": "ins",
        "id": "ins0",
        "rate_hz": RATE_HZ,
        "drift_m_per_sqrt_s": 0.1,
        "altitude_sigma_m": 0.5,
        "velocity_sigma_mps": 0.03,
    },
]


@pytest.fixture(scope="module")
def run() -> tuple[dict[str, Any], dict[str, Any]]:
    doc = nav_scenario(
        duration_s=DURATION_S,
        truth_rate_hz=0.01,
        legs=[{"duration_s": DURATION_S, "turn_rate_dps": 1.0}],  # circles: the heading wraps every 360 s
        sensors=SENSORS,
    )
    sim = build(parse_scenario(doc, "stats"), seed=2024)
    events = list(stamp(sim.raw_events(), player_source("stats")))
    return sensor_stats(events, sim.context.platforms), error_series(events, sim.context.platforms)


def _white(st: dict[str, Any], sigma: float, bias: float) -> None:
    """A white-noise component: chi-square on the SD, normal on the mean."""
    n = st["count"]
    assert n == N
    q = (n - 1) * st["sd"] ** 2 / sigma**2
    assert chi2.ppf(ALPHA / 2, n - 1) <= q <= chi2.ppf(1 - ALPHA / 2, n - 1), (st["sd"], sigma)
    assert abs(st["mean"] - bias) <= Z * sigma / math.sqrt(n), (st["mean"], bias)


def _correlated(st: dict[str, Any], sigma_gm: float, sigma_w: float, bias: float) -> None:
    """Bias + Gauss-Markov(sigma_gm, a) + white(sigma_w): normal theory with the autocovariance sums."""
    n = st["count"]
    var = sigma_gm**2 + sigma_w**2
    sum_c = sigma_gm**2 * (1 + A) / (1 - A) + sigma_w**2
    sum_c2 = sigma_gm**4 * (1 + A**2) / (1 - A**2) + 2 * sigma_gm**2 * sigma_w**2 + sigma_w**4
    assert abs(st["mean"] - bias) <= Z * math.sqrt(sum_c / n), (st["mean"], bias)
    expected_s2 = var - sum_c / n  # E[s^2] is lowered slightly by estimating the mean
    assert abs(st["sd"] ** 2 - expected_s2) <= Z * math.sqrt(2 * sum_c2 / n), (st["sd"], math.sqrt(var))


def test_dvl_and_speed_log_white_noise_and_bias(run: tuple[dict[str, Any], dict[str, Any]]) -> None:
    stats, _ = run
    dvl = stats[keys.sensor("auv1", "dvl", "dvl0")]["errors"]
    for comp, bias in zip(("v_forward_mps", "v_starboard_mps", "v_down_mps"), (0.02, -0.01, 0.005), strict=True):
        _white(dvl[comp], 0.05, bias)
    log = stats[keys.sensor("auv1", "speed_log", "log0")]["errors"]
    for comp in ("v_forward_mps", "v_starboard_mps", "v_down_mps"):
        _white(log[comp], 0.1, 0.0)


def test_heading_gauss_markov_has_the_stationary_sigma_and_correlation_time(
    run: tuple[dict[str, Any], dict[str, Any]],
) -> None:
    stats, series = run
    key = keys.sensor("auv1", "heading", "gm")
    _correlated(stats[key]["errors"]["heading_rad"], math.radians(2.0), 0.0, 0.0)
    e = series[key]["errors"]["heading_rad"]
    e = e - e.mean()
    r1 = float(np.dot(e[1:], e[:-1]) / np.dot(e, e))
    assert abs(r1 - A) <= Z * math.sqrt((1 - A**2) / N), (r1, A)  # Bartlett: Var r1 = (1 - a^2) / N for AR(1)


def test_heading_bias_plus_gauss_markov_plus_white(run: tuple[dict[str, Any], dict[str, Any]]) -> None:
    stats, _ = run
    st = stats[keys.sensor("auv1", "heading", "full")]["errors"]["heading_rad"]
    _correlated(st, math.radians(1.0), math.radians(0.5), math.radians(0.5))


def test_depth_white_noise_and_bias(run: tuple[dict[str, Any], dict[str, Any]]) -> None:
    stats, _ = run
    _white(stats[keys.sensor("auv1", "depth", "press0")]["errors"]["depth_m"], 0.1, 0.05)


def test_ins_random_walk_drift_and_white_altitude_and_velocity(run: tuple[dict[str, Any], dict[str, Any]]) -> None:
    stats, series = run
    key = keys.sensor("auv1", "ins", "ins0")
    st = stats[key]["errors"]
    _white(st["h_m"], 0.5, 0.0)
    for comp in ("vx_mps", "vz_mps", "vh_mps"):
        _white(st[comp], 0.03, 0.0)
    for comp in ("x_m", "z_m"):
        err = series[key]["errors"][comp]
        assert abs(err[0]) < 1e-9  # initial_sigma_m = 0
        steps = np.diff(err)  # random-walk increments: white, sigma = q sqrt(dt)
        n = steps.size
        q = (n - 1) * float(np.var(steps, ddof=1)) / (0.1**2 / RATE_HZ)
        assert chi2.ppf(ALPHA / 2, n - 1) <= q <= chi2.ppf(1 - ALPHA / 2, n - 1)
        assert abs(float(np.mean(steps))) <= Z * 0.1 / math.sqrt(n)
        s = steps - steps.mean()
        assert abs(float(np.dot(s[1:], s[:-1]) / np.dot(s, s))) <= Z / math.sqrt(n)  # independent increments


def test_heading_messages_stay_in_range_through_north(run: tuple[dict[str, Any], dict[str, Any]]) -> None:
    _, series = run
    key = keys.sensor("auv1", "heading", "full")
    assert np.all(np.abs(series[key]["errors"]["heading_rad"]) < math.radians(10))  # no 2 pi jumps
