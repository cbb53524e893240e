"""PCL tracker core: the bad-input rules of digest 003 §5.6, ordering, resets, snapshots and metrics helpers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from schemas.base import Header
from schemas.pcl_tracker import BISTATIC, PclScanReport, PclTrackReport
from schemas.radar import BistaticConfigUpdate, BistaticPlot, BistaticScan
from services.pcl_tracker.config import PclTrackerConfig
from services.pcl_tracker.core import PclTracker
from services.pcl_tracker.geometry import h_b
from services.pcl_tracker.metrics import ospa, run_metrics
from services.pcl_tracker.models import cv_process_noise, cv_transition
from services.pcl_tracker.simulation import scan_from_bistatic
from shared.estimates import CV_STATE, gaussian
from shared.filters.angles import wrap_pi
from shared.filters.covariance import CholeskyStats, robust_cholesky
from shared.service import InputRejected

TX = np.array([8000.0, 0.0, 300.0])
D2R = math.pi / 180.0
SIG = np.array([200.0, 0.5 * D2R, 0.5 * D2R, 5.0])
NS = 1_000_000_000


def truth_state(t: float) -> np.ndarray:
    c = 256.0 * D2R
    v = np.array([200.0 * math.sin(c), 200.0 * math.cos(c), 0.0])
    return np.concatenate([np.array([9000.0, 5000.0, 1000.0]) + v * t, v])


def noisy_z(rng: np.random.Generator, t: float) -> np.ndarray:
    z = h_b(truth_state(t), TX) + rng.standard_normal(4) * SIG
    z[1] = wrap_pi(z[1])
    return z


def scan(k: int, rows: list[np.ndarray] | np.ndarray, **kw: object) -> BistaticScan:
    return scan_from_bistatic(k, (k - 1) * 3 * NS, np.asarray(rows).reshape(-1, 4), **kw)  # type: ignore[arg-type]


def plot(pid: str, z: np.ndarray, **kw: object) -> BistaticPlot:
    base: dict[str, object] = {
        "plot_id": pid,
        "azimuth_deg": math.degrees(z[1]),
        "elevation_deg": math.degrees(z[2]),
        "bistatic_range_m": float(z[0]),
        "bistatic_velocity_mps": float(z[3]),
        "sigma_rb_m": 200.0,
        "sigma_az_deg": 0.5,
        "sigma_el_deg": 0.5,
        "sigma_vb_mps": 5.0,
    }
    base.update(kw)
    return BistaticPlot.model_construct(**base)  # type: ignore[arg-type]


def scan_of(k: int, plots: list[BistaticPlot], stamp_ns: int | None = None) -> BistaticScan:
    return BistaticScan.model_construct(
        header=Header(stamp_ns=(k - 1) * 3 * NS if stamp_ns is None else stamp_ns),
        receiver_id="rx1",
        illuminator_id="tx-fm-98.1",
        scan_id=k,
        plots=plots,
    )


def warm_tracker(n: int = 8, seed: int = 1, cfg: PclTrackerConfig | None = None) -> tuple[PclTracker, list]:
    rng = np.random.default_rng(seed)
    trk = PclTracker(cfg or PclTrackerConfig.paper())
    reps = []
    for k in range(1, n + 1):
        reps.extend(trk.step(scan(k, [noisy_z(rng, 3.0 * (k - 1))])))
    return trk, reps


def assert_state_valid(trk: PclTracker) -> None:
    for tr in trk.tracks.values():
        assert np.all(np.isfinite(tr.x)) and np.all(np.isfinite(tr.P))
        np.testing.assert_array_equal(tr.P, tr.P.T)
        assert float(np.min(np.linalg.eigvalsh(tr.P))) > 0.0


# ------------------------------------------------------------------------------------------------ plot rules
def test_nan_and_inf_plots_are_rejected_and_never_used() -> None:
    trk, _ = warm_tracker()
    z = noisy_z(np.random.default_rng(2), 24.0)
    bad = [
        plot("n1", z, bistatic_range_m=math.nan),
        plot("n2", z, bistatic_velocity_mps=math.inf),
        plot("n3", z, azimuth_deg=math.nan),
        plot("n4", z, elevation_deg=-math.inf),
    ]
    rep = trk.step(scan_of(9, bad))[0]
    assert rep.n_plots_rejected == {"nan": 4}
    assert rep.n_plots_in == 4 and rep.n_associated == 0 and rep.n_candidates == 0
    assert rep.tracks[0].coasted
    assert_state_valid(trk)


def test_bad_sigmas_are_replaced_by_the_defaults_and_flagged() -> None:
    z = noisy_z(np.random.default_rng(3), 24.0)
    ref_trk, _ = warm_tracker()
    ref = ref_trk.step(scan_of(9, [plot("a", z)]))[0]
    for bad in ({"sigma_rb_m": -1.0}, {"sigma_az_deg": 0.0}, {"sigma_el_deg": math.nan}, {"sigma_vb_mps": 51.0}):
        trk, _ = warm_tracker()
        rep = trk.step(scan_of(9, [plot("a", z, **bad)]))[0]
        assert "sigma_defaulted" in rep.flags and rep.n_plots_flagged.get("sigma_defaulted") == 1
        assert rep.tracks[0].estimate.mean == ref.tracks[0].estimate.mean
    # absent sigmas take the defaults silently
    trk, _ = warm_tracker()
    nosig = plot("a", z, sigma_rb_m=None, sigma_az_deg=None, sigma_el_deg=None, sigma_vb_mps=None)
    rep = trk.step(scan_of(9, [nosig]))[0]
    assert "sigma_defaulted" not in rep.flags and rep.tracks[0].estimate.mean == ref.tracks[0].estimate.mean


def test_negative_bistatic_range_is_clamped_near_the_baseline_else_rejected() -> None:
    trk = PclTracker(PclTrackerConfig.paper())
    z = np.array([0.0, 0.0, 0.01, 0.0])
    rep = trk.step(scan_of(1, [plot("a", z, bistatic_range_m=-500.0), plot("b", z, bistatic_range_m=-700.0)]))[0]
    assert rep.n_plots_flagged.get("near_baseline") == 1 and "near_baseline" in rep.flags
    assert rep.n_plots_rejected == {"rb_below_baseline": 1}
    assert rep.n_candidates == 0  # r_b = 0 is below rb_min_convertible: never used for initiation


def test_out_of_range_plots_are_rejected() -> None:
    trk = PclTracker(PclTrackerConfig.paper())
    z = np.array([10_000.0, 0.5, 0.05, 100.0])
    plots = [
        plot("a", z, bistatic_range_m=250_000.0),
        plot("b", z, bistatic_velocity_mps=-950.0),
        plot("c", z, elevation_deg=89.5),
        plot("d", z, elevation_deg=-6.0),
        plot("e", z),
    ]
    rep = trk.step(scan_of(1, plots))[0]
    assert rep.n_plots_rejected == {"out_of_range": 4}
    assert rep.n_candidates == 1


def test_azimuth_is_wrapped_not_rejected_and_range_forms_are_equivalent() -> None:
    rng = np.random.default_rng(4)
    zs = [noisy_z(rng, 3.0 * k) for k in range(6)]
    L = float(np.linalg.norm(TX))
    c = 299_792_458.0
    lam = 3.06

    def run(form: str) -> list[list[float]]:
        trk = PclTracker(PclTrackerConfig.paper())
        out = []
        for k, z in enumerate(zs, start=1):
            p = plot("a", z)
            if form == "wrapped":
                p = plot("a", z, azimuth_deg=math.degrees(z[1]) + 720.0)
            elif form == "sum":
                p = plot("a", z, bistatic_range_m=None, range_sum_m=float(z[0]) + L)
            elif form == "delay":
                p = plot("a", z, bistatic_range_m=None, delay_s=float(z[0]) / c)
            elif form == "doppler":
                p = plot("a", z, bistatic_velocity_mps=None, doppler_hz=float(z[3]) / (-1.0 * lam))
            out.extend(r.tracks[0].estimate.mean for r in trk.step(scan_of(k, [p])) if r.tracks)
        return out

    ref = run("plain")
    assert len(ref) == 5
    for form in ("wrapped", "sum", "delay", "doppler"):
        np.testing.assert_allclose(run(form), ref, rtol=1e-6, atol=1e-3)


def test_doppler_without_wavelength_and_duplicate_plot_ids_are_rejected() -> None:
    cfg = PclTrackerConfig.model_validate({"geometry": {"wavelength_m": None}})
    trk = PclTracker(cfg)
    z = np.array([10_000.0, 0.5, 0.05, 100.0])
    p = plot("a", z, bistatic_velocity_mps=None, doppler_hz=10.0)
    rep = trk.step(scan_of(1, [p, plot("b", z), plot("b", z)]))[0]
    assert rep.n_plots_rejected == {"no_wavelength": 1, "duplicate_plot_id": 1}


def test_low_rb_plot_is_a_hit_without_update_and_never_initiates() -> None:
    cfg = PclTrackerConfig.paper().with_limits(rb_min_convertible_m=20_000.0)  # make the paper target "low r_b"
    rng = np.random.default_rng(5)
    trk = PclTracker(cfg)
    reps = []
    for k in range(1, 4):
        reps.extend(trk.step(scan(k, [noisy_z(rng, 3.0 * (k - 1))])))
    assert all(not r.tracks for r in reps) and reps[-1].n_candidates == 0
    # with a track from convertible plots, low-r_b hits keep it alive with the state at the prediction
    trk, _ = warm_tracker()
    trk.config = trk.config.with_limits(rb_min_convertible_m=20_000.0)
    before = trk.tracks[1]
    x0, P0 = before.x.copy(), before.P.copy()
    rep = trk.step(scan(9, [noisy_z(rng, 24.0)]))[0]
    tr = rep.tracks[0]
    F = cv_transition(3.0)[0]
    Q = cv_process_noise(3.0, 0.01)[0]
    assert tr.associated_plot_id is not None and tr.consecutive_misses == 0 and not tr.updated
    assert "low_rb_hit" in tr.flags
    np.testing.assert_allclose(tr.estimate.mean, F @ x0, rtol=1e-12)
    np.testing.assert_allclose(tr.estimate.covariance, F @ P0 @ F.T + Q, rtol=1e-9)


# ------------------------------------------------------------------------------------------------ ordering
def _scans(n: int, seed: int = 6) -> list[BistaticScan]:
    rng = np.random.default_rng(seed)
    return [scan(k, [noisy_z(rng, 3.0 * (k - 1))]) for k in range(1, n + 1)]


def test_reorder_window_processes_swapped_scans_in_order() -> None:
    scans = _scans(10)
    ref_trk = PclTracker(PclTrackerConfig.paper())
    ref = [r for s in scans for r in ref_trk.step(s)]
    trk = PclTracker(PclTrackerConfig.paper())
    order = [0, 1, 2, 4, 3, 5, 7, 6, 8, 9]
    out = []
    sizes = []
    for i in order:
        res = trk.step(scans[i])
        sizes.append(len(res))
        out.extend(res)
    assert sizes == [1, 1, 1, 0, 2, 1, 0, 2, 1, 1]
    assert [r.scan_id for r in out] == list(range(1, 11))
    assert [r.model_dump() for r in out] == [r.model_dump() for r in ref]


def test_late_and_duplicate_scans_are_dropped_never_run_backwards() -> None:
    scans = _scans(8)
    trk = PclTracker(PclTrackerConfig.paper())
    for s in scans[:6]:
        trk.step(s)
    snap = trk.snapshot()
    with pytest.raises(InputRejected) as info:
        trk.step(scans[5])
    assert info.value.reason == "duplicate_scan" and "same" in info.value.detail
    with pytest.raises(InputRejected) as info:
        trk.step(scans[5].model_copy(update={"plots": []}))
    assert info.value.reason == "duplicate_scan" and "different" in info.value.detail
    with pytest.raises(InputRejected) as info:
        trk.step(scans[0])
    assert info.value.reason in {"late_scan_dropped", "duplicate_scan"}
    # a scan missing beyond the reorder window: 8 arrives, then 9 -> 7 is given up; late 7 is dropped
    trk2 = PclTracker.restore(snap)
    assert trk2.step(scans[7]) == []
    extra = scan(9, [noisy_z(np.random.default_rng(1), 24.0)])
    reps = trk2.step(extra)
    assert [r.scan_id for r in reps] == [8, 9] and reps[0].gap_scans == 1
    with pytest.raises(InputRejected) as info:
        trk2.step(scans[6])
    assert info.value.reason == "late_scan_dropped"
    nxt = trk2.step(scan(10, []))[0]
    assert "late_scan_dropped" in nxt.flags
    assert_state_valid(trk2)


def test_non_increasing_time_is_rejected_and_counted_as_a_gap() -> None:
    scans = _scans(8)
    trk = PclTracker(PclTrackerConfig.paper())
    for s in scans[:5]:
        trk.step(s)
    bad = scans[5].model_copy(update={"header": Header(stamp_ns=scans[4].header.stamp_ns)})
    with pytest.raises(InputRejected) as info:
        trk.step(bad)
    assert info.value.reason == "time_not_monotonic"
    rep = trk.step(scans[6])[0]  # not held back waiting for scan 6
    assert rep.scan_id == 7 and rep.gap_scans == 1 and "gap_coast" in rep.flags
    assert rep.tracks[0].status == "CONFIRMED"


def test_gap_misses_count_and_a_large_gap_resets_everything() -> None:
    trk, _ = warm_tracker()
    rep = trk.step(scan(11, []))  # 9 and 10 missing: buffered (window 1), then released as a 2-scan gap
    assert rep == []
    rep = trk.step(scan(12, []))
    assert [r.scan_id for r in rep] == [11, 12]
    assert rep[0].gap_scans == 2 and rep[0].tracks[0].status == "DROPPED"  # 2 gap misses + 1 = K
    trk, _ = warm_tracker()
    trk.config = trk.config.with_limits(reorder_window_scans=0)
    rep = trk.step(scan(30, []))[0]
    assert "gap_reset" in rep.flags and rep.tracks[0].drop_reason == "reset"
    assert not trk.tracks and not trk.candidates


def test_wrong_pair_is_rejected_and_tx_change_resets() -> None:
    trk, _ = warm_tracker()
    other = scan(9, [], receiver_id="rx2")
    with pytest.raises(InputRejected) as info:
        trk.step(other)
    assert info.value.reason == "wrong_pair"
    hdr = Header(stamp_ns=25 * NS)
    same = BistaticConfigUpdate(
        header=hdr, receiver_id="rx1", illuminator_id="tx-fm-98.1", tx_position_enu_m=[8000.0, 0.0, 300.0]
    )
    assert trk.step(same) == [] and len(trk.tracks) == 1
    moved = same.model_copy(update={"tx_position_enu_m": [9000.0, 0.0, 300.0], "wavelength_m": 3.0})
    rep = trk.step(moved)[0]
    assert rep.trigger == "config" and rep.tracks[0].drop_reason == "reset" and "config_reset" in rep.flags
    assert not trk.tracks and trk.L_m == pytest.approx(math.hypot(9000.0, 300.0)) and trk.wavelength_m == 3.0


def test_clutter_burst_suppresses_initiation_but_not_association() -> None:
    cfg = PclTrackerConfig.paper().with_limits(max_plots_per_scan=20)
    trk, _ = warm_tracker(cfg=cfg)
    rng = np.random.default_rng(8)
    z = noisy_z(rng, 24.0)
    clutter = np.column_stack(
        [
            rng.uniform(5_000, 50_000, 40),
            rng.uniform(-math.pi, math.pi, 40),
            rng.uniform(0.0, 0.5, 40),
            rng.uniform(-400, 400, 40),
        ]
    )
    rep = trk.step(scan(9, [z, *clutter], plot_ids=["t"] + [f"c{i}" for i in range(40)]))[0]
    assert "clutter_burst" in rep.flags
    assert rep.tracks[0].associated_plot_id == "t" and rep.n_candidates == 0 and rep.n_initiated == 0


def test_median_based_burst_detection() -> None:
    cfg = PclTrackerConfig.paper().with_limits(burst_min_plots=30, burst_factor=5.0)
    trk, _ = warm_tracker(cfg=cfg)
    rng = np.random.default_rng(9)
    clutter = np.column_stack(
        [rng.uniform(5e3, 5e4, 60), rng.uniform(-3, 3, 60), rng.uniform(0, 0.5, 60), rng.uniform(-400, 400, 60)]
    )
    rep = trk.step(scan(9, clutter))[0]
    assert "clutter_burst" in rep.flags and rep.n_candidates == 0


def test_tentative_capacity_drops_the_weakest() -> None:
    cfg = PclTrackerConfig.paper().with_tracker(confirm_M=3, confirm_N=4).with_limits(max_tentative_tracks=2)
    trk = PclTracker(cfg)
    rng = np.random.default_rng(10)
    base = np.array([20_000.0, 0.3, 0.05, 100.0])
    s1 = [base + np.array([i * 3000.0, 0.2 * i, 0.0, 0.0]) for i in range(4)]
    s2 = [z + np.array([-0.0, 0.0, 0.0, 0.0]) + rng.normal(0, 1, 4) * [10, 1e-4, 1e-4, 0.1] for z in s1]
    trk.step(scan(1, s1))
    rep = trk.step(scan(2, s2))[0]
    reasons = [t.drop_reason for t in rep.tracks if t.status == "DROPPED"]
    assert rep.n_initiated == 4 and reasons == ["capacity", "capacity"] and rep.n_tentative == 2
    assert "capacity" in rep.flags


def test_robust_cholesky_fallbacks() -> None:
    stats = CholeskyStats()
    good = np.eye(3)[None] * 4.0
    nearly = np.array([[[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]])  # PSD, singular
    indefinite = np.array([[[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]])
    D = robust_cholesky(np.concatenate([good, nearly, indefinite]), stats)
    assert stats.jitter == 1 and stats.eig_clip == 1
    np.testing.assert_allclose(D[0] @ D[0].T, good[0])
    np.testing.assert_allclose(D[1] @ D[1].T, nearly[0], atol=1e-6)
    w, V = np.linalg.eigh(indefinite[0])
    np.testing.assert_allclose(D[2] @ D[2].T, (V * np.maximum(w, 0)) @ V.T, atol=1e-12)


# ------------------------------------------------------------------------------------------------ state & API
def test_snapshot_restore_continues_identically() -> None:
    scans = _scans(20)
    a = PclTracker(PclTrackerConfig.paper())
    for s in scans[:10]:
        a.step(s)
    b = PclTracker.restore(a.snapshot())
    ra = [r.model_dump() for s in scans[10:] for r in a.step(s)]
    rb = [r.model_dump() for s in scans[10:] for r in b.step(s)]
    assert ra == rb


def test_on_demand_prediction_does_not_change_state() -> None:
    trk, reps = warm_tracker()
    tr = reps[-1].tracks[0]
    p = trk.predict(1, 21 * NS + 2 * NS)
    F = cv_transition(2.0)[0]
    Q = cv_process_noise(2.0, 0.01)[0]
    np.testing.assert_allclose(p.estimate.mean, F @ np.array(tr.estimate.mean), rtol=1e-12)
    np.testing.assert_allclose(p.estimate.covariance, F @ np.array(tr.estimate.covariance) @ F.T + Q, rtol=1e-9)
    assert trk.tracks[1].t_ns == 21 * NS


def test_outputs_are_stamped_from_the_data() -> None:
    _, reps = warm_tracker()
    assert [r.header.stamp_ns for r in reps] == [(k - 1) * 3 * NS for k in range(1, 9)]
    assert all(r.t_s == pytest.approx(r.header.stamp_ns * 1e-9) for r in reps)


# ------------------------------------------------------------------------------------------------ metrics
def make_report(scan_id: int, tracks: list[tuple[int, list[float]]]) -> PclScanReport:
    cov6 = np.eye(6).tolist()
    cov4 = np.eye(4).tolist()
    reps = [
        PclTrackReport(
            track_id=tid,
            status="CONFIRMED",
            scan_id=scan_id,
            t_s=float(scan_id),
            estimate=gaussian("pcl_enu", CV_STATE, [*map(float, pos), 0.0, 0.0, 0.0], cov6),
            bistatic=gaussian("bistatic/rx1/fm", BISTATIC, [1.0, 0.0, 0.0, 0.0], cov4),
            hits=2,
            consecutive_misses=0,
            age_scans=0,
            created_scan_id=1,
        )
        for tid, pos in tracks
    ]
    return PclScanReport(
        header=Header(stamp_ns=scan_id * NS),
        receiver_id="rx1",
        illuminator_id="tx",
        scan_id=scan_id,
        t_s=1.0 * scan_id,
        tracks=reps,
    )


def test_ospa_against_a_hand_computed_case() -> None:
    X = np.array([[0.0, 0.0], [10.0, 0.0]])
    Y = np.array([[0.0, 3.0]])
    # one pair at distance 3 (the other point is unassigned: cut-off c = 5 as cardinality penalty)
    assert ospa(X, Y, c=5.0, p=1.0) == pytest.approx((3.0 + 5.0) / 2.0)
    assert ospa(X, Y, c=5.0, p=2.0) == pytest.approx(math.sqrt((9.0 + 25.0) / 2.0))
    assert ospa(Y, X, c=5.0, p=2.0) == pytest.approx(math.sqrt(17.0))
    # optimal assignment, not greedy: greedy would pair (1, 0)-(1, 1) first
    A = np.array([[0.0, 0.0], [2.0, 0.0]])
    B = np.array([[1.0, 0.0], [3.1, 0.0]])
    assert ospa(A, B, c=100.0, p=1.0) == pytest.approx((1.0 + 1.1) / 2.0)
    assert ospa(np.zeros((0, 3)), np.zeros((0, 3)), c=7.0) == 0.0
    assert ospa(np.zeros((0, 3)), np.ones((2, 3)), c=7.0) == 7.0


def test_run_metrics_counts_swaps_breaks_and_false_tracks() -> None:
    truth = np.zeros((4, 1, 6))
    truth[:, 0, :3] = [[0, 0, 0], [100, 0, 0], [200, 0, 0], [300, 0, 0]]
    reports = [
        make_report(1, [(1, [10, 0, 0]), (9, [50_000, 0, 0])]),
        make_report(2, [(1, [110, 0, 0])]),
        make_report(3, [(2, [205, 0, 0])]),  # id swap 1 -> 2
        make_report(4, []),  # break
    ]
    m = run_metrics(reports, truth, [1, 2, 3, 4], ospa_c_m=1000.0, match_distance_m=500.0)
    # track 1 ends and track 2 takes the target over: an ID switch, and a restart (not a swap between targets)
    assert m["id_switches"] == 1 and m["id_restarts"] == 1 and m["id_swaps"] == 0
    assert m["assignment_changes"] == 1 and m["breaks"] == 1 and m["fragmentations"] == 0
    assert m["false_confirmed_tracks"] == 1 and m["n_confirmed_tracks"] == 3
    assert m["ospa_m"][0] == pytest.approx(math.sqrt((10.0**2 + 1000.0**2) / 2.0))
    assert m["ospa_m"][3] == 1000.0
    assert m["pos_sq_err_m2"][:3] == pytest.approx([100.0, 100.0, 25.0])


def test_sigma_points_below_zero_range_are_clamped_and_flagged() -> None:
    from services.pcl_tracker.filter import convert_plots
    from services.pcl_tracker.geometry import h_a3

    z3 = np.array([[650.0, 0.3, 0.05], [5000.0, 0.3, 0.05]])
    s3 = np.array([[400.0, 0.01, 0.01], [200.0, 0.01, 0.01]])  # 650 - sqrt(3) 400 < 0 for the first plot
    conv = convert_plots(z3, s3, TX)
    assert conv.clamped.tolist() == [True, False] and conv.valid.all()
    assert np.all(np.isfinite(conv.y)) and np.all(np.linalg.eigvalsh(conv.R) > 0)
    p, clamped, valid = h_a3(np.array([-5.0, 0.3, 0.05]), TX)
    assert bool(clamped) and bool(valid)
    np.testing.assert_allclose(p, h_a3(np.array([1e-3, 0.3, 0.05]), TX)[0])
