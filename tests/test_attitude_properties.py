"""Property-based tests (Hypothesis) of the attitude core's input handling, for both presets.

Whatever a radar sends -- valid-but-extreme plots (1 m or 2,000 km away, elevations a hair from the zenith,
azimuths beyond +-360 deg, per-plot sigmas from micrometres to kilometres), time going backwards, duplicate
stamps, long gaps, site messages in between -- ``AttitudeCore.step`` either returns schema-valid estimates or
refuses the input with ``InputRejected``; it never raises anything else, and every target's state stays a finite
estimate with a symmetric positive-definite covariance. A refused plot leaves the state exactly as it was.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from schemas import Header, RadarPlot, RadarSite, TrackEnd
from services.attitude.config import AttitudeConfig
from services.attitude.core import AttitudeCore
from shared.service import InputRejected

NS = 1_000_000_000
PRESETS = ("manoeuvre", "paper")

finite = {"allow_nan": False, "allow_infinity": False}
#: one input: (kind, dt from the previous input in s (may be negative or zero), range m, az deg, el deg, sigmas)
inputs = st.tuples(
    st.sampled_from(["plot"] * 8 + ["site", "end"]),
    st.one_of(st.sampled_from([5.0, 5.0, 5.0, 0.0, 1e-4, -5.0, 60.0]), st.floats(-30.0, 600.0, **finite)),
    st.one_of(st.floats(1.0, 2.0e6, **finite), st.sampled_from([1.0, 2.0e6, 50e3])),
    st.floats(-720.0, 720.0, **finite),
    st.one_of(st.floats(-89.999, 89.999, **finite), st.sampled_from([89.999, -89.999, 0.0])),
    st.one_of(st.none(), st.tuples(*(st.floats(1e-6, 1e4, **finite),) * 3)),
    st.sampled_from(["a", "a", "b"]),
)


def _state_ok(core: AttitudeCore) -> None:
    for site, target in core.targets():
        snap = core.snapshot(target, site)
        if snap.x is None:
            continue
        assert snap.p is not None and np.isfinite(snap.x).all() and np.isfinite(snap.p).all()
        assert np.array_equal(snap.p, snap.p.T)
        np.linalg.cholesky(snap.p)  # positive definite by the core's own criterion (Cholesky succeeds)
        if snap.model_probabilities is not None:
            mu = snap.model_probabilities
            assert np.all(mu >= 0.0) and math.isclose(float(mu.sum()), 1.0, abs_tol=1e-9)


def _message(kind: str, stamp_ns: int, r: float, az: float, el: float, sig, target: str):
    header = Header(stamp_ns=stamp_ns)
    if kind == "site":
        s = sig or (225.0, 0.35, 0.3)
        return RadarSite(
            header=header,
            site_id="r1",
            lat_deg=0.0,
            lon_deg=0.0,
            h_m=0.0,
            sigma_r_m=s[0],
            sigma_az_deg=min(s[1], 180.0),
            sigma_el_deg=min(s[2], 90.0),
            scan_period_s=5.0,
        )
    if kind == "end":
        return TrackEnd(header=header, site_id="r1", target_id=target)
    extra = {} if sig is None else {"sigma_r_m": sig[0], "sigma_az_deg": sig[1], "sigma_el_deg": sig[2]}
    return RadarPlot(header=header, site_id="r1", target_id=target, range_m=r, az_deg=az, el_deg=el, **extra)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seq=st.lists(inputs, min_size=1, max_size=40), preset=st.sampled_from(PRESETS))
def test_core_never_raises_out_and_keeps_its_state_intact(seq, preset) -> None:
    core = AttitudeCore(AttitudeConfig(preset=preset, validate_covariances=True, coast_output=True))
    t_s = 1000.0
    for kind, dt, r, az, el, sig, target in seq:
        t_s = max(0.0, t_s + dt)
        msg = _message(kind, round(t_s * NS), r, az, el, sig, target)
        before = {k: core.snapshot(k[1], k[0]) for k in core.targets()}
        try:
            outs = core.step(msg)
        except InputRejected as exc:
            assert exc.reason  # refused with a reason code, state untouched
            for key, snap in before.items():
                now = core.snapshot(key[1], key[0])
                assert now.t_ns == snap.t_ns and now.n_updates == snap.n_updates
                if snap.x is not None:
                    assert np.array_equal(now.x, snap.x) and np.array_equal(now.p, snap.p)
            _state_ok(core)
            continue
        for est in outs:  # schema-valid by construction (validate_covariances=True re-checks PSD)
            assert est.site_id == "r1"
            for f in ("psi_deg", "theta_deg", "gamma_deg", "psi_los_deg", "sigma_psi_los_deg"):
                v = getattr(est, f)
                assert v is None or math.isfinite(v)
        _state_ok(core)


@settings(max_examples=25, deadline=None)
@given(
    dts=st.lists(st.sampled_from([5.0, 5.0, 5.0, -5.0, 0.0, 0.0005, 12.0]), min_size=5, max_size=40),
    preset=st.sampled_from(PRESETS),
)
def test_time_going_backwards_or_repeating_is_refused_and_changes_nothing(dts, preset) -> None:
    """Out-of-order and duplicate plots of a straight flight are refused (out_of_order, duplicate_time); the
    estimates of the accepted plots equal those of a core that never saw the refused ones."""
    core = AttitudeCore(AttitudeConfig(preset=preset))
    clean = AttitudeCore(AttitudeConfig(preset=preset))
    t_last, t = None, 100.0
    for dt in dts:
        t += dt
        stamp = round(t * NS)
        x = 200e3 - 200.0 * t  # inbound along the x axis at 200 m/s, never overhead
        plot = RadarPlot(
            header=Header(stamp_ns=stamp),
            site_id="r1",
            target_id="t",
            range_m=math.hypot(x, 5e3),
            az_deg=30.0,
            el_deg=math.degrees(math.atan2(5e3, x)),
        )
        refused = t_last is not None and (stamp < t_last or abs(stamp - t_last) < 1_000_000)
        try:
            got = core.step(plot)
        except InputRejected as exc:
            assert refused and exc.reason in ("out_of_order", "duplicate_time")
            continue
        assert not refused
        ref = clean.step(plot)
        assert [o.estimate and o.estimate.mean for o in got] == [o.estimate and o.estimate.mean for o in ref]
        assert [o.status for o in got] == [o.status for o in ref]
        t_last = stamp
