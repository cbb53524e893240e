"""Property-based tests (Hypothesis) of the PCL tracker core and its service handler under hostile input.

Generated message sequences mix a real target's plots with floods of clutter (1,200 plots in a scan),
duplicate plot ids, NaN/inf and absurd values, bad sigmas, repeated, late and skipped scan ids, stamps that go
backwards, and transmitter changes, for both presets. Whatever arrives:

* ``PclTracker.step`` raises nothing but :class:`InputRejected` (its refusal, turned into a diagnostic by the
  service), and its state stays intact: finite states, symmetric positive-definite covariances, IMM model
  probabilities that are probabilities, unique ids below ``next_track_id``, ``last_scan_id`` never
  decreasing; every report it emits passes the schema's validation;
* a snapshot taken anywhere restores a tracker that produces the same reports as the original;
* the service handler fed the same messages, plus undecodable bytes, never fails internally and its
  counters add up (received = accepted + rejected).
"""

from __future__ import annotations

import contextlib
import json
import math
from typing import Any

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from schemas.base import Header
from schemas.pcl_tracker import PclScanReport
from schemas.radar import BistaticConfigUpdate, BistaticPlot, BistaticScan
from services.pcl_tracker.config import PclTrackerConfig
from services.pcl_tracker.core import PclTracker
from services.pcl_tracker.geometry import h_b
from services.pcl_tracker.service import PclTrackerService, input_key
from services.pcl_tracker.settings import PclTrackerSettings
from shared import codec
from shared.service import InputRejected

NS = 1_000_000_000
TX = np.array([8000.0, 0.0, 300.0])
KEY = input_key("rx1", "tx-fm-98.1")
WEIRD = [math.nan, math.inf, -math.inf, 0.0, -1.0, 1e300, -1e300, 5e-324]


def target_plot(t_s: float, rng: np.random.Generator, pid: str) -> BistaticPlot:
    c = math.radians(256.0)
    v = np.array([200.0 * math.sin(c), 200.0 * math.cos(c), 0.0])
    x = np.concatenate([np.array([9000.0, 5000.0, 1000.0]) + v * t_s, v])
    z = h_b(x, TX) + rng.standard_normal(4) * np.array([200.0, math.radians(0.5), math.radians(0.5), 5.0])
    return BistaticPlot.model_construct(
        plot_id=pid,
        azimuth_deg=math.degrees(z[1]),
        elevation_deg=math.degrees(z[2]),
        bistatic_range_m=float(z[0]),
        bistatic_velocity_mps=float(z[3]),
        range_sum_m=None,
        delay_s=None,
        doppler_hz=None,
        sigma_rb_m=200.0,
        sigma_az_deg=0.5,
        sigma_el_deg=0.5,
        sigma_vb_mps=5.0,
        snr_db=20.0,
    )


def clutter_plots(rng: np.random.Generator, n: int, weird: float, dup: float) -> list[BistaticPlot]:
    """n plots over (and beyond) the measurement box; a fraction ``weird`` of the fields is replaced by
    NaN/inf/0/negative/huge values, a fraction ``dup`` of the ids repeats an earlier one."""
    out = []
    for i in range(n):
        f = {
            "bistatic_range_m": float(rng.uniform(-2e3, 3e5)),
            "azimuth_deg": float(rng.uniform(-720, 720)),
            "elevation_deg": float(rng.uniform(-20, 100)),
            "bistatic_velocity_mps": float(rng.uniform(-1200, 1200)),
            "sigma_rb_m": float(rng.uniform(-10, 3000)),
            "sigma_az_deg": float(rng.uniform(0, 6)),
            "sigma_el_deg": 0.5,
            "sigma_vb_mps": 5.0,
            "snr_db": float(rng.uniform(0, 40)),
        }
        for k in list(f):
            if rng.random() < weird:
                f[k] = WEIRD[int(rng.integers(len(WEIRD)))]
        pid = f"c{int(rng.integers(i)) if i and rng.random() < dup else i}"
        out.append(
            BistaticPlot.model_construct(plot_id=pid, range_sum_m=None, delay_s=None, doppler_hz=None, **f)  # type: ignore[arg-type]
        )
    return out


op = st.one_of(
    st.tuples(
        st.just("scan"),
        st.sampled_from([1, 1, 1, 1, 2, 0, -1, 13]),  # scan id step: next, gap, repeat, late, reset-size gap
        st.sampled_from([3.0, 3.0, 3.0, 1e-9, 0.0, -2.0, 40.0]),  # time step, s (zero and backwards included)
        st.sampled_from([0, 0, 3, 20, 1200]),  # clutter plots (1,200: a flood beyond max_plots_per_scan)
        st.sampled_from([0.0, 0.0, 0.05, 0.5]),  # fraction of weird fields
        st.sampled_from([0.0, 0.2]),  # fraction of duplicate plot ids
        st.booleans(),  # the target is detected
    ),
    st.tuples(st.just("config"), st.sampled_from([(8000.0, 0.0, 300.0), (8100.0, 0.0, 300.0), (math.nan, 0.0, 0.0)])),
)


def messages(ops: list[tuple[Any, ...]], seed: int) -> list[BistaticScan | BistaticConfigUpdate]:
    rng = np.random.default_rng(seed)
    out: list[BistaticScan | BistaticConfigUpdate] = []
    sid, t = 0, 0.0
    for o in ops:
        if o[0] == "config":
            out.append(
                BistaticConfigUpdate.model_construct(
                    header=Header(stamp_ns=max(round(t * NS), 0)),
                    receiver_id="rx1",
                    illuminator_id="tx-fm-98.1",
                    tx_position_enu_m=list(o[1]),
                    wavelength_m=None,
                )
            )
            continue
        _, dsid, dt, n_cl, weird, dup, detected = o
        sid, t = max(sid + dsid, 1), max(t + dt, 0.0)
        plots = clutter_plots(rng, n_cl, weird, dup)
        if detected:
            plots.insert(int(rng.integers(len(plots) + 1)), target_plot(t, rng, "tgt"))
        out.append(
            BistaticScan.model_construct(
                header=Header(stamp_ns=round(t * NS)),
                receiver_id="rx1",
                illuminator_id="tx-fm-98.1",
                scan_id=sid,
                plots=plots,
            )
        )
    return out


def schema_valid(msgs: list) -> list:
    """What the service passes to the core: the plots that validate (it drops the others at decoding)."""
    out = []
    for m in msgs:
        if isinstance(m, BistaticScan):
            kept = []
            for p in m.plots:
                with contextlib.suppress(ValueError):
                    kept.append(BistaticPlot.model_validate(p.model_dump()))
            m = m.model_copy(update={"plots": kept})
        out.append(m)
    return out


def config(preset: str) -> PclTrackerConfig:
    return PclTrackerConfig.paper() if preset == "paper" else PclTrackerConfig()


def assert_intact(trk: PclTracker, last_sid: int | None) -> None:
    ids = sorted(trk.tracks)
    assert all(0 < i < trk.next_track_id for i in ids)
    if last_sid is not None:
        assert trk.last_scan_id is not None and trk.last_scan_id >= last_sid
    for tr in trk.tracks.values():
        assert np.all(np.isfinite(tr.x)) and np.all(np.isfinite(tr.P))
        np.testing.assert_allclose(tr.P, tr.P.T, rtol=0, atol=1e-9 * float(np.abs(tr.P).max()))
        assert np.linalg.eigvalsh(tr.P).min() > 0.0
        if tr.mu is not None:
            assert tr.xm is not None and tr.Pm is not None
            assert np.all(tr.mu >= 0.0) and abs(float(tr.mu.sum()) - 1.0) < 1e-9
            assert np.all(np.isfinite(tr.xm)) and np.all(np.isfinite(tr.Pm))
            assert np.linalg.eigvalsh(tr.Pm).min() > 0.0


def run(trk: PclTracker, msgs: list) -> list[PclScanReport]:
    out: list[PclScanReport] = []
    for m in msgs:
        before = trk.last_scan_id
        # InputRejected is the core's refusal (the service turns it into a diagnostic); anything else fails the test
        with contextlib.suppress(InputRejected):
            out += trk.step(m)
        assert_intact(trk, before)
    return out


SETTINGS = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@SETTINGS
@given(
    ops=st.lists(op, min_size=1, max_size=14),
    seed=st.integers(0, 2**32 - 1),
    preset=st.sampled_from(["robust", "paper"]),
)
def test_core_survives_any_input_and_stays_intact(ops: list, seed: int, preset: str) -> None:
    trk = PclTracker(config(preset))
    reports = run(trk, messages(ops, seed))
    reports += trk.flush()
    assert_intact(trk, None)
    for r in reports:  # what the core builds without validation is what validation accepts
        assert PclScanReport.model_validate(r.model_dump()) == r


@SETTINGS
@given(
    ops=st.lists(op, min_size=2, max_size=12),
    cut=st.integers(0, 12),
    seed=st.integers(0, 2**32 - 1),
    preset=st.sampled_from(["robust", "paper"]),
)
def test_snapshot_anywhere_restores_the_same_tracker(ops: list, cut: int, seed: int, preset: str) -> None:
    msgs = schema_valid(messages(ops, seed))  # a snapshot holds recent scans, which the schema must accept
    cut = min(cut, len(msgs))
    a = PclTracker(config(preset))
    run(a, msgs[:cut])
    b = PclTracker.restore(json.loads(json.dumps(a.snapshot())))
    assert run(a, msgs[cut:]) + a.flush() == run(b, msgs[cut:]) + b.flush()


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    ops=st.lists(op, min_size=1, max_size=10),
    garbage=st.lists(st.binary(max_size=64), max_size=4),
    seed=st.integers(0, 2**32 - 1),
)
def test_service_handler_never_fails_and_counts_everything(ops: list, garbage: list[bytes], seed: int) -> None:
    svc = PclTrackerService(PclTrackerSettings(instance="prop"))
    svc._subs = svc.subscriptions()
    payloads: list[tuple[bytes, str]] = []
    for m in messages(ops, seed):
        try:
            payloads.append((codec.encode(m), codec.encoding_of(type(m))))
        except (ValueError, TypeError):  # the wire refuses NaN: send its plots through raw msgpack instead
            payloads.append(
                (
                    codec.encode(m.model_copy(update={"plots": []})) if isinstance(m, BistaticScan) else b"\x00",
                    codec.encoding_of(type(m)),
                )
            )
    payloads += [(g, codec.encoding_of(BistaticScan)) for g in garbage]
    for p, enc in payloads:
        svc.process(KEY, p, enc, rx_time_ns=0)
    c = svc.counters
    assert c.received == len(payloads) and c.accepted + c.rejected == c.received
    assert "internal_error" not in c.rejected_by_reason
    assert_intact(svc.core, None)


def test_plots_a_nanosecond_apart_do_not_start_a_track() -> None:
    """Found by the properties above: a pair 1 ns apart gave angle rates of variance 2 sigma^2 / tau^2 ~ 1e14 and a
    covariance that was not positive definite. Closer than ``min_init_interval_s`` (0.5 s) no pair is formed;
    3 s apart it is."""
    rng = np.random.default_rng(3)
    for dt_s, expect in ((1e-9, 0), (0.4, 0), (3.0, 1)):
        trk = PclTracker(PclTrackerConfig.paper())
        trk.step(messages([("scan", 1, 0.0, 0, 0.0, 0.0, True)], 1)[0])
        second = BistaticScan.model_construct(
            header=Header(stamp_ns=round(dt_s * NS)),
            receiver_id="rx1",
            illuminator_id="tx-fm-98.1",
            scan_id=2,
            plots=[target_plot(dt_s, rng, "tgt")],
        )
        assert trk.step(second)[0].n_initiated == expect, dt_s
        assert_intact(trk, None)
