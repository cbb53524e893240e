"""The fixed-lag smoother of the attitude IMM (``services/attitude/smoother.py``, ``smoother_lag_scans``).

* one linear model: the smoothed estimate of the plot L back is the Rauch-Tung-Striebel smoother's over the plots
  up to now (filterpy's ``rts_smoother``, an independent implementation), to round-off, for a CA and a Singer
  model and irregular steps;
* the CT model's cross-covariance of the predicted state with the lagged ones (quadrature over the turn rate)
  against Monte Carlo, and equal to Phi B for a known turn rate;
* the smoother never changes a real-time output (L = 0 is the current IMM; L > 0 adds SMOOTHED estimates with
  the stamps of the plots L back), also under Hypothesis' extreme, out-of-order and duplicate inputs;
* a lag's block does not depend on the depth of the augmentation (lag 1 of an L = 3 smoother is the L = 1
  smoother's);
* the service publishes the smoothed estimates on ``<target>/smoothed``.
"""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO, fixstream_cmd
from filterpy.kalman import rts_smoother
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_attitude_properties import _message, inputs

from schemas import Header, RadarPlot
from services.attitude import imm, smoother
from services.attitude.config import MANOEUVRE_MODELS, AttitudeConfig, MotionModel
from services.attitude.core import AttitudeCore
from services.attitude.geometry import convert_plot
from services.attitude.initiation import fsf_estimate
from services.attitude.models import OMEGA, _singer_transition, ct_cross_covariance, ct_transitions
from services.attitude.service import SMOOTHED_SUBKEY, AttitudeService, AttitudeSettings, output_key
from services.attitude.simulation import NS, FlightPlan, Segment, fly, measure, scan_times
from shared.errors import InputRejected

CA = MotionModel(name="ca", kind="ca", sigma_jerk_mps3=0.3, sojourn_s=100.0)
SINGER = MotionModel(name="singer", kind="singer", sigma_accel_mps2=2.0, tau_s=10.0, sojourn_s=100.0)
TURN = MANOEUVRE_MODELS[1]
assert TURN.kind == "ct"


def _turn_plan() -> FlightPlan:
    """200 m/s level, a 30 deg-bank turn of 40 s between straight legs, 20-40 km from the radar."""
    return FlightPlan(
        (30e3, 4e3, 20e3),
        200.0,
        90.0,
        0.0,
        (
            Segment(80.0),
            Segment(3.0, bank_deg=(0.0, 30.0)),
            Segment(40.0, bank_deg=(30.0, 30.0)),
            Segment(3.0, bank_deg=(30.0, 0.0)),
        ),
    )


def _plots(times: np.ndarray, seed: int, target: str = "t") -> list[RadarPlot]:
    meas = measure(fly(_turn_plan(), times), AttitudeConfig().measurement_sigmas(), np.random.default_rng(seed))
    return [
        RadarPlot(header=Header(stamp_ns=round(t * NS)), site_id="r1", target_id=target, range_m=r, az_deg=a, el_deg=e)
        for t, (r, a, e) in zip(times.tolist(), meas[0].tolist(), strict=True)
    ]


def _converted(plots: list[RadarPlot]) -> list[tuple[np.ndarray, np.ndarray]]:
    sig = AttitudeConfig().measurement_sigmas()
    return [
        convert_plot(
            p.range_m,
            math.radians(p.az_deg),
            math.radians(p.el_deg),
            sig.sigma_r_m,
            math.radians(sig.sigma_az_deg),
            math.radians(sig.sigma_el_deg),
        )
        for p in plots
    ]


# ------------------------------------------------------------------------------ one linear model = RTS smoother
@pytest.mark.parametrize("model", [CA, SINGER], ids=["ca", "singer"])
def test_one_linear_model_gives_the_rts_smoother(model: MotionModel) -> None:
    """With one model the IMM is a Kalman filter and the augmented state's lag-l block is E[alpha(t_k-l) | z_1..k]:
    filterpy's RTS smoother over the filtered estimates up to t_k must give the same mean and covariance."""
    rng = np.random.default_rng(4)
    times = np.cumsum(np.r_[0.0, rng.uniform(3.0, 7.0, 39)])  # irregular steps
    zs = _converted(_plots(times, seed=11))
    x, p = fsf_estimate(times[:3] - times[2], np.stack([z for z, _ in zs[:3]]), np.stack([r for _, r in zs[:3]]))
    models = (model,)
    state = imm.ImmState.start(x, p, (1.0,), models)
    lag_max = 3
    lag = smoother.LagState.empty(1, 9)
    # filterpy's Fs[i], Qs[i] take step i to step i + 1 (the last pair is unused)
    filt_x, filt_p, fs, qs = [state.xs[0].copy()], [state.ps[0].copy()], [], []
    t_prev = round(times[2] * NS)
    checked = 0
    for k in range(3, len(times)):
        dt = float(times[k] - times[k - 1])
        z, rz = zs[k]
        c, xp, pp = imm.predict(state, models, dt)
        res = imm.update_models(c, xp, pp, z, rz, models)
        lag = smoother.step(lag, state, models, dt, xp, pp, z, rz, res.state, t_prev, lag_max)
        state, t_prev = res.state, round(times[k] * NS)
        f, q = imm.model_matrices(model, dt)
        filt_x.append(state.xs[0].copy())
        filt_p.append(state.ps[0].copy())
        fs.append(np.array(f))
        qs.append(np.array(q))
        xs_rts, ps_rts, _, _ = rts_smoother(
            np.array(filt_x), np.array(filt_p), np.array([*fs, np.eye(9)]), np.array([*qs, np.zeros((9, 9))])
        )
        for ell in range(1, lag.depth + 1):
            stamp, xl, pl = lag.smoothed(state.mu, ell)
            assert stamp == round(times[k - ell] * NS)
            np.testing.assert_allclose(xl, xs_rts[-1 - ell], rtol=1e-9, atol=1e-7)
            scale = np.sqrt(np.outer(np.diag(ps_rts[-1 - ell]), np.diag(ps_rts[-1 - ell])))
            np.testing.assert_array_less(np.abs(pl - ps_rts[-1 - ell]) / scale, 1e-8)
            checked += 1
    assert checked == 3 * (len(times) - 3) - 3  # depth 1, 2, then 3 from the third step on


# ------------------------------------------------------------------------------ the CT model's cross-covariance
def _ct_case(rng: np.random.Generator, sigma_omega: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A 10-state (turning at 0.05 rad/s, 200 m/s) and 9 other variables y, jointly Gaussian with a random
    covariance: (mean, covariance (19 x 19), the 10-state's part, cov(alpha, y))."""
    scales = np.array([50.0, 5.0, 2.0, 50.0, 3.0, 0.5, 50.0, 5.0, 2.0, sigma_omega] + [60.0, 6.0, 2.0] * 3)
    a = rng.standard_normal((19, 19))
    corr = a @ a.T + 19.0 * np.eye(19)
    d = 1.0 / np.sqrt(np.diag(corr))
    cov = (corr * np.outer(d, d)) * np.outer(scales, scales)
    mean = np.zeros(19)
    mean[[0, 1, 2, 3, 6, 7, 8, 9]] = [20e3, 150.0, -6.0, 4e3, 15e3, 130.0, 7.5, 0.05]
    mean[10:] = mean[:9] - [1e3, 0, 0, 0, 0, 0, 1e3, 0, 0]
    return mean, cov, cov[:10, :10], cov[:10, 10:]


def test_ct_cross_covariance_matches_monte_carlo() -> None:
    """cov(alpha~, y) of the quadrature against 200,000 draws of (alpha, y) propagated by the exact transition at
    each drawn turn rate (sigma_omega = 0.1 rad/s: 30 deg of heading over the step): within 5 standard errors of
    every element; the first-order answer (the transition at the mean rate times B) is not."""
    rng = np.random.default_rng(2)
    dt, sa, tau = 5.0, TURN.sigma_accel_mps2, TURN.tau_s
    assert sa is not None and tau is not None
    mean, cov, p10, b = _ct_case(rng, 0.1)
    got = ct_cross_covariance(mean[:10], p10, b, dt, sa, tau)
    n = 200_000
    draws = rng.multivariate_normal(mean, cov, size=n)
    phi = ct_transitions(draws[:, OMEGA], dt, tau)
    horiz, vert = [0, 1, 2, 6, 7, 8], [3, 4, 5]
    new = np.empty((n, 10))
    new[:, horiz] = np.einsum("nij,nj->ni", phi, draws[:, horiz])
    new[:, vert] = draws[:, vert] @ _singer_transition(dt, sa, tau).T
    new[:, OMEGA] = draws[:, OMEGA]
    y = draws[:, 10:]
    dn, dy = new - new.mean(axis=0), y - y.mean(axis=0)
    mc = dn.T @ dy / (n - 1)
    se = np.sqrt(np.outer((dn * dn).mean(axis=0), (dy * dy).mean(axis=0)) / n)  # >= the element's standard error
    assert np.max(np.abs(got - mc) / se) < 5.0
    phi_mean = np.zeros((10, 10))
    phi_mean[np.ix_(horiz, horiz)] = ct_transitions(np.array([mean[OMEGA]]), dt, tau)[0]
    phi_mean[np.ix_(vert, vert)] = _singer_transition(dt, sa, tau)
    phi_mean[OMEGA, OMEGA] = 1.0
    assert np.max(np.abs(phi_mean @ b - mc) / se) > 20.0


def test_ct_cross_covariance_for_a_known_turn_rate_is_phi_b() -> None:
    rng = np.random.default_rng(3)
    mean, _, p10, b = _ct_case(rng, 0.1)
    p10[OMEGA, :] = p10[:, OMEGA] = 0.0
    b[OMEGA] = 0.0
    got = ct_cross_covariance(mean[:10], p10, b, 5.0, 0.3, 5.0)
    phi = np.zeros((9, 9))
    phi[np.ix_([0, 1, 2, 6, 7, 8], [0, 1, 2, 6, 7, 8])] = ct_transitions(np.array([mean[OMEGA]]), 5.0, 5.0)[0]
    phi[np.ix_([3, 4, 5], [3, 4, 5])] = _singer_transition(5.0, 0.3, 5.0)
    np.testing.assert_allclose(got[:9], phi @ b[:9], rtol=1e-12, atol=1e-9)
    assert not got[OMEGA].any()


# ------------------------------------------------------------------------------ the core: real time unchanged
def _run(core: AttitudeCore, plots: list[RadarPlot]) -> list:
    return [est for pl in plots for est in core.step(pl)]


#: the default bank with the CT model predicted by its EKF (the smoother's other cross-covariance path)
EKF_BANK = tuple(m.model_copy(update={"ct_prediction": "ekf"}) if m.kind == "ct" else m for m in MANOEUVRE_MODELS)


@pytest.mark.parametrize(("lag", "bank"), [(1, MANOEUVRE_MODELS), (3, MANOEUVRE_MODELS), (2, EKF_BANK)])
def test_smoother_leaves_the_real_time_estimates_and_adds_the_lagged_ones(lag: int, bank: tuple) -> None:
    """L = 0 is the current IMM (no SMOOTHED output); with L > 0 the real-time outputs are bit-identical and each
    plot from the (L + 1)-th after the start adds one SMOOTHED estimate with the stamp of the plot L back."""
    plots = _plots(scan_times(40, 5.0), seed=5)
    base = _run(AttitudeCore(AttitudeConfig(imm_models=bank)), plots)
    assert not any("SMOOTHED" in e.flags for e in base)
    out = _run(AttitudeCore(AttitudeConfig(imm_models=bank, smoother_lag_scans=lag)), plots)
    realtime = [e for e in out if "SMOOTHED" not in e.flags]
    assert [e.model_dump() for e in realtime] == [e.model_dump() for e in base]
    smoothed = [e for e in out if "SMOOTHED" in e.flags]
    stamps = [p.header.stamp_ns for p in plots]
    first = 2  # the FSF start is at the third plot
    assert [e.header.stamp_ns for e in smoothed] == stamps[first : len(stamps) - lag]
    for e in smoothed:
        assert e.nis is None and e.flags[0] == "SMOOTHED" and e.estimate is not None and e.psi_deg is not None


def test_a_lag_block_does_not_depend_on_the_depth() -> None:
    """The augmented IMM's blocks 0..l evolve on their own: lag 1 of an L = 3 smoother is the L = 1 smoother's."""
    plots = _plots(scan_times(30, 5.0), seed=6)
    one = [e for e in _run(AttitudeCore(AttitudeConfig(smoother_lag_scans=1)), plots) if "SMOOTHED" in e.flags]
    core = AttitudeCore(AttitudeConfig(smoother_lag_scans=3))
    track_lag1 = []
    for pl in plots:
        core.step(pl)
        tr = core._tracks[("r1", "t")]
        if tr.lag is not None and tr.lag.depth >= 1 and tr.imm is not None:
            track_lag1.append(tr.lag.smoothed(tr.imm.mu, 1))
    assert len(track_lag1) == len(one)
    for e, (stamp, x, _) in zip(one, track_lag1, strict=True):
        assert e.header.stamp_ns == stamp
        np.testing.assert_allclose(e.estimate.mean, x, rtol=1e-9, atol=1e-6)


def test_smoothed_heading_is_better_in_a_turn() -> None:
    """On 8 runs of the 30 deg turn (9S15 errors), the lag-3 smoothed heading's RMS over the turn and the 20 s after
    it is below the real-time estimate's at the same stamps: the smoother sees the turn 15 s earlier."""
    times = scan_times(60, 5.0)
    truth = fly(_turn_plan(), times)
    true_psi = {round(t * NS): math.degrees(p) for t, p in zip(times.tolist(), truth.psi.tolist(), strict=True)}
    window = {round(t * NS) for t in times.tolist() if 80.0 <= t <= 146.0}
    sq: dict[bool, list[float]] = {False: [], True: []}
    for seed in range(8):
        for e in _run(AttitudeCore(AttitudeConfig(smoother_lag_scans=3)), _plots(times, seed=100 + seed)):
            if e.header.stamp_ns in window and e.psi_deg is not None:
                err = (e.psi_deg - true_psi[e.header.stamp_ns] + 180.0) % 360.0 - 180.0
                sq["SMOOTHED" in e.flags].append(err * err)
    rms = {k: math.sqrt(sum(v) / len(v)) for k, v in sq.items()}
    assert rms[True] < 0.7 * rms[False]


def test_smoother_needs_the_imm() -> None:
    with pytest.raises(ValueError, match="smoother_lag_scans"):
        AttitudeConfig(preset="paper", smoother_lag_scans=2)
    assert AttitudeConfig(preset="paper").smoother_lag_scans == 0


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seq=st.lists(inputs, min_size=1, max_size=40), lag=st.integers(1, 3))
def test_smoother_never_crashes_and_never_changes_real_time_outputs(seq, lag: int) -> None:
    """Extreme-but-valid plots, time backwards, duplicates, long gaps, site messages and track ends: the core with
    the smoother refuses exactly what the core without it refuses, publishes the same real-time estimates, and its
    SMOOTHED estimates are schema-valid (covariances checked) with finite lagged states."""
    plain = AttitudeCore(AttitudeConfig(validate_covariances=True))
    smooth = AttitudeCore(AttitudeConfig(validate_covariances=True, smoother_lag_scans=lag))
    t_s = 1000.0
    for kind, dt, r, az, el, sig, target in seq:
        t_s = max(0.0, t_s + dt)
        msg = _message(kind, round(t_s * NS), r, az, el, sig, target)
        try:
            a = plain.step(msg)
        except InputRejected as exc:
            with pytest.raises(InputRejected) as again:
                smooth.step(msg)
            assert again.value.reason == exc.reason
            continue
        b = smooth.step(msg)
        assert [e.model_dump() for e in b if "SMOOTHED" not in e.flags] == [e.model_dump() for e in a]
        for e in b:
            if "SMOOTHED" in e.flags:
                assert e.estimate is not None and np.isfinite(e.estimate.mean).all()
        for tr in smooth._tracks.values():
            if tr.lag is not None:
                assert np.isfinite(tr.lag.xl).all() and np.isfinite(tr.lag.pl).all() and np.isfinite(tr.lag.pc).all()


# ------------------------------------------------------------------------------ the service
def test_service_publishes_the_smoothed_estimates_on_their_own_key() -> None:
    svc = AttitudeService(AttitudeSettings(instance="r1", smoother_lag_scans=2))
    key = "fixstream/sensor/r1/radar/plots"
    outs = [o for pl in _plots(scan_times(12, 5.0), seed=7) for o in svc.on_input(key, pl)]
    fix = output_key("r1", "t")
    smoothed = [o for o in outs if o.key == f"{fix}/{SMOOTHED_SUBKEY}"]
    assert len(smoothed) == 12 - 2 - 2 and all("SMOOTHED" in o.msg.flags for o in smoothed)
    assert not any("SMOOTHED" in o.msg.flags for o in outs if o.key == fix)
    assert len([o for o in outs if o.key == fix]) == 12


def test_fixstream_mc_scores_the_smoothed_stream_when_asked(tmp_path: Path) -> None:
    """``params.stream: smoothed`` through the CLI: the same runs scored on the smoothed stream have a lower turn
    heading RMS than on the real-time stream (the smoother's purpose: it sees L scans past each plot), the
    metrics say which stream they score, and a smoothed stream with no lag is refused before any run."""
    doc = yaml.safe_load((REPO / "scenarios" / "attitude_turns_light.yaml").read_text())
    results = {}
    for stream in ("realtime", "smoothed"):
        doc["estimators"][0]["params"] = {"reference": False, "config": {"smoother_lag_scans": 3}, "stream": stream}
        scenario = tmp_path / f"{stream}.yaml"
        scenario.write_text(yaml.safe_dump(doc))
        out = tmp_path / f"{stream}.json"
        proc = subprocess.run(
            fixstream_cmd("mc", str(scenario), "--runs", "2", "--seed", "5", "--out", str(out), "--workers", "1"),
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert proc.returncode == 0, proc.stderr[-3000:]
        results[stream] = json.loads(out.read_text())
    per_run = [r["per_run"][0]["estimators"]["r1"] for r in results.values()]
    assert "stream" not in per_run[0]["params"] and per_run[1]["params"]["stream"] == "smoothed"
    turn = [r["aggregate"]["estimators"]["r1"]["phases"]["turn"]["rms_deg"]["psi"] for r in results.values()]
    assert turn[1] < 0.8 * turn[0], turn
    doc["estimators"][0]["params"] = {"reference": False, "stream": "smoothed"}
    scenario.write_text(yaml.safe_dump(doc))
    proc = subprocess.run(
        fixstream_cmd("mc", str(scenario), "--runs", "1", "--out", str(tmp_path / "x.json")),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2 and "smoother_lag_scans" in proc.stderr, proc.stderr[-2000:]
