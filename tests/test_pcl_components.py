"""The PCL tracker's components (issue 19) against independent computations, and swapping one.

* predictor + updater against FilterPy: the paper's update (linear KF on the converted plot, H = [I_3 0],
  digest 003 §2.6 step 6) against ``filterpy.kalman.KalmanFilter``, and the 4-D bistatic UKF update
  against ``filterpy.kalman.UnscentedKalmanFilter`` with Julier's points, kappa = 0 (= the paper's 2n points
  of weight 1/(2n), §2.2);
* the associator's assignment against brute force over every one-to-one assignment of small
  Hypothesis-generated cost matrices (GNN: most gated pairs, then least total cost), and the component
  (gate + confirmed-first assignment) against d² computed here;
* the confirmer and the deleter against the definitions of M/N (§2.5) and K misses (§2.7);
* a tracker given another associator behaves as that associator says.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from filterpy.kalman import JulierSigmaPoints, KalmanFilter, UnscentedKalmanFilter
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from schemas.radar import BistaticScan
from services.pcl_tracker.association import GatedPairs, assign_pairs
from services.pcl_tracker.associator import Association, GatedAssociator
from services.pcl_tracker.config import PclTrackerConfig
from services.pcl_tracker.core import PclTracker
from services.pcl_tracker.deleter import MissDeleter, MofNConfirmer
from services.pcl_tracker.filter import ConvertedPlots
from services.pcl_tracker.geometry import h_b
from services.pcl_tracker.plots import NormalisedPlots
from services.pcl_tracker.predictor import BistaticPredictor, Prediction
from services.pcl_tracker.simulation import scan_from_bistatic
from services.pcl_tracker.state import TrackState
from services.pcl_tracker.updater import PclUpdater
from shared.filters.unscented import TransformResult

CFG = PclTrackerConfig.paper()
TX = np.array(CFG.geometry.tx_position_enu_m, dtype=np.float64)
D2R = math.pi / 180.0
SIG = np.array([200.0, 0.5 * D2R, 0.5 * D2R, 5.0])  # sigma of r_b (m), alpha, eps (rad), v_b (m/s)
NS = 1_000_000_000
SCALE = np.array([100.0, 100.0, 100.0, 10.0, 10.0, 10.0])  # sqrt of the typical P_a diagonal (m, m/s)

unit = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


def spd(a: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """A symmetric positive-definite matrix D (A A^T + I/2) D, D = diag(scale)."""
    return scale[:, None] * (a @ a.T + 0.5 * np.eye(len(scale))) * scale[None, :]


def state_near(offset: np.ndarray) -> np.ndarray:
    """A Cartesian state around (9, 5, 1) km moving at ~200 m/s (alpha ≈ 61°: no wrap near ±180°)."""
    return np.array([9000.0, 5000.0, 1000.0, -190.0, -50.0, 0.0]) + offset * SCALE


def track(x: np.ndarray, P: np.ndarray, status: str = "CONFIRMED", track_id: int = 1) -> TrackState:
    return TrackState(track_id=track_id, status=status, phase="ukf", x=x.copy(), P=P.copy(), t_ns=0, created_scan=0)


def one_plot(z: np.ndarray) -> NormalisedPlots:
    return NormalisedPlots(["p"], z[None], SIG[None], np.array([math.nan]), np.zeros(1, dtype=bool))


# ------------------------------------------------------------------------------------------------ updater


@settings(max_examples=40, deadline=None)
@given(
    a=arrays(np.float64, (6, 6), elements=unit),
    b=arrays(np.float64, (3, 3), elements=unit),
    dx=arrays(np.float64, 6, elements=unit),
    dy=arrays(np.float64, 3, elements=unit),
    tau=st.floats(0.5, 10.0),
)
def test_cv_predictor_and_position_updater_are_the_linear_kalman_filter(
    a: np.ndarray, b: np.ndarray, dx: np.ndarray, dy: np.ndarray, tau: float
) -> None:
    """§1.6 + §2.6 step 6: x_a(k|k) from FilterPy's KalmanFilter (F, Q of the CV model, H = [I_3 0], R_a(k))."""
    x0, P0 = state_near(dx), spd(a, SCALE)
    R = spd(b, SCALE[:3])
    y = x0[:3] + tau * x0[3:] + 100.0 * dy
    q = CFG.tracker.q_accel_var_m2s4
    kf = KalmanFilter(dim_x=6, dim_z=3)
    kf.x, kf.P = x0.copy(), P0.copy()
    kf.F = np.block([[np.eye(3), tau * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
    kf.Q = q * np.block(
        [[tau**4 / 4 * np.eye(3), tau**3 / 2 * np.eye(3)], [tau**3 / 2 * np.eye(3), tau**2 * np.eye(3)]]
    )
    kf.H = np.hstack([np.eye(3), np.zeros((3, 3))])
    kf.R = R
    kf.predict()
    x_pred, P_pred = kf.x.copy(), kf.P.copy()
    kf.update(y)

    tr = track(x0, P0)
    pred = BistaticPredictor(CFG.tracker).predict([tr], np.array([tau]), TX)
    np.testing.assert_allclose(tr.x, x_pred, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(tr.P, P_pred, rtol=1e-10, atol=1e-8)
    conv = ConvertedPlots(y[None], R[None], np.ones(1, dtype=bool), np.zeros(1, dtype=bool))
    z = h_b(x_pred, TX)
    updated, skipped = PclUpdater(CFG.tracker).update(
        [tr], pred, {0: 0}, one_plot(z), np.diag(SIG**2)[None], conv, {0: 0}
    )
    assert updated == [0] and not skipped
    np.testing.assert_allclose(tr.x, kf.x, rtol=1e-10, atol=1e-6)
    np.testing.assert_allclose(tr.P, kf.P, rtol=1e-8, atol=1e-6 * float(np.abs(kf.P).max()))


@settings(max_examples=30, deadline=None)
@given(
    a=arrays(np.float64, (6, 6), elements=unit),
    dx=arrays(np.float64, 6, elements=unit),
    dz=arrays(np.float64, 4, elements=unit),
    tau=st.floats(1.0, 5.0),
)
def test_bistatic_ukf_update_is_filterpys_unscented_filter(
    a: np.ndarray, dx: np.ndarray, dz: np.ndarray, tau: float
) -> None:
    """§2.6 [D] ``bistatic_ukf4``: predict, inverse UT through h_b and UKF update, as FilterPy's UKF with
    Julier's sigma points, kappa = 0 (2n points of weight 1/(2n); the central point has weight 0)."""
    cfg = CFG.with_tracker(measurement_model="bistatic_ukf4")
    x0, P0 = state_near(dx), spd(a, SCALE)
    F = np.block([[np.eye(3), tau * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
    q = cfg.tracker.q_accel_var_m2s4
    R = np.diag(SIG**2)
    ukf = UnscentedKalmanFilter(
        dim_x=6, dim_z=4, dt=tau, hx=lambda x: h_b(x, TX), fx=lambda x, dt: F @ x, points=JulierSigmaPoints(6, 0.0)
    )
    ukf.x, ukf.P, ukf.R = x0.copy(), P0.copy(), R
    ukf.Q = q * np.block(
        [[tau**4 / 4 * np.eye(3), tau**3 / 2 * np.eye(3)], [tau**3 / 2 * np.eye(3), tau**2 * np.eye(3)]]
    )
    ukf.predict()
    z = h_b(ukf.x, TX) + dz * 2.0 * SIG
    ukf.update(z)

    tr = track(x0, P0)
    pred = BistaticPredictor(cfg.tracker).predict([tr], np.array([tau]), TX)
    np.testing.assert_allclose(z - pred.images.mean[0], ukf.y, rtol=1e-6, atol=1e-8)  # nu = z - z_b(k|k-1)
    np.testing.assert_allclose(pred.images.cov[0] + R, ukf.S, rtol=1e-7, atol=1e-12)
    conv = ConvertedPlots(np.zeros((1, 3)), np.eye(3)[None], np.ones(1, dtype=bool), np.zeros(1, dtype=bool))
    PclUpdater(cfg.tracker).update([tr], pred, {0: 0}, one_plot(z), R[None], conv, {0: 0})
    np.testing.assert_allclose(tr.x, ukf.x, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(tr.P, ukf.P, rtol=1e-6, atol=1e-7 * float(np.abs(ukf.P).max()))


def test_updater_leaves_low_rb_and_unconvertible_hits_at_the_prediction() -> None:
    """A low-r_b plot, or one whose conversion failed, is a hit without update (flags say which)."""
    P0 = np.diag(SCALE**2)
    trs = [track(state_near(np.zeros(6)), P0, track_id=k) for k in (1, 2)]
    pred = BistaticPredictor(CFG.tracker).predict(trs, np.array([3.0, 3.0]), TX)
    before = [(t.x.copy(), t.P.copy()) for t in trs]
    z = pred.images.mean.copy()
    plots = NormalisedPlots(["a", "b"], z, np.stack([SIG, SIG]), np.full(2, math.nan), np.array([True, False]))
    conv = ConvertedPlots(z[:, :3], np.stack([np.eye(3)] * 2), np.array([False, False]), np.zeros(2, dtype=bool))
    updated, skipped = PclUpdater(CFG.tracker).update(
        trs, pred, {0: 0, 1: 1}, plots, np.stack([np.diag(SIG**2)] * 2), conv, {0: 0, 1: 1}
    )
    assert updated == [] and skipped == {0: "low_rb_hit", 1: "conversion_failed"}
    for t, (x, P) in zip(trs, before, strict=True):
        assert np.array_equal(t.x, x) and np.array_equal(t.P, P)


# ------------------------------------------------------------------------------------------------ associator


def brute_force(cost: np.ndarray, gated: np.ndarray, rows: list[int], cols: list[int]) -> tuple[int, float]:
    """(most gated pairs, least total cost among those) over every one-to-one assignment of rows to cols."""
    best = (0, 0.0)
    for choice in itertools.product([None, *cols], repeat=len(rows)):
        used = [c for c in choice if c is not None]
        if len(used) != len(set(used)):
            continue
        if any(c is not None and not gated[r, c] for r, c in zip(rows, choice, strict=True)):
            continue
        n = len(used)
        total = sum(float(cost[r, c]) for r, c in zip(rows, choice, strict=True) if c is not None)
        if n > best[0] or (n == best[0] and total < best[1]):
            best = (n, total)
    return best


def check_optimal(
    pairs: list[tuple[int, int]], cost: np.ndarray, gated: np.ndarray, rows: list[int], cols: list[int]
) -> None:
    assert len({r for r, _ in pairs}) == len(pairs) and len({c for _, c in pairs}) == len(pairs)  # one-to-one
    assert all(r in rows and c in cols and gated[r, c] for r, c in pairs)
    n, total = brute_force(cost, gated, rows, cols)
    assert len(pairs) == n
    assert sum(float(cost[r, c]) for r, c in pairs) == pytest.approx(total, rel=1e-12, abs=1e-9)


@settings(max_examples=150, deadline=None)
@given(
    shape=st.tuples(st.integers(1, 4), st.integers(1, 5)),
    data=st.data(),
)
def test_gnn_assignment_is_the_brute_force_optimum(shape: tuple[int, int], data: st.DataObject) -> None:
    """GNN over the gated pairs: the most pairs, then the least total cost (cost may be negative: + ln det S)."""
    T, P = shape
    cost = data.draw(arrays(np.float64, (T, P), elements=st.floats(-5.0, 20.0)))
    gated = data.draw(arrays(np.bool_, (T, P)))
    ti, pj = np.nonzero(gated)
    gp = GatedPairs(ti.astype(np.int64), pj.astype(np.int64), cost[ti, pj], np.zeros(ti.size))
    pairs = assign_pairs(gp, gp.d2, np.ones(T, dtype=bool), np.ones(P, dtype=bool), "gnn")
    check_optimal(pairs, cost, gated, list(range(T)), list(range(P)))


@settings(max_examples=60, deadline=None)
@given(
    n=st.tuples(st.integers(1, 4), st.integers(1, 4)),
    data=st.data(),
)
def test_associator_gates_then_assigns_confirmed_tracks_first(n: tuple[int, int], data: st.DataObject) -> None:
    """The component: d² = nu^T (R_b(k|k-1) + R_b)^-1 nu <= gamma_4 computed here; confirmed tracks take the
    optimal assignment first, tentative tracks the optimal one over the plots left."""
    T, P = n
    off_t = data.draw(arrays(np.float64, (T, 4), elements=st.floats(-2.0, 2.0)))
    off_p = data.draw(arrays(np.float64, (P, 4), elements=st.floats(-2.0, 2.0)))
    confirmed = data.draw(arrays(np.bool_, T))
    z0 = np.array([10_000.0, 0.5, 0.05, 100.0])
    z_pred, z = z0 + off_t * SIG, z0 + off_p * SIG
    R_pred = np.stack([np.diag((0.5 * SIG) ** 2)] * T)
    R_plot = np.stack([np.diag(SIG**2)] * P)
    trs = [track(np.zeros(6), np.eye(6), "CONFIRMED" if c else "TENTATIVE", i + 1) for i, c in enumerate(confirmed)]
    pred = Prediction(TransformResult(z_pred, R_pred, np.zeros((T, 0, 0))))
    assoc = GatedAssociator(CFG.tracker).associate(trs, pred, z, R_plot)

    d2 = np.empty((T, P))
    for i, j in itertools.product(range(T), range(P)):
        nu = z[j] - z_pred[i]
        nu[1] = math.remainder(nu[1], 2.0 * math.pi)
        d2[i, j] = nu @ np.linalg.solve(R_pred[i] + R_plot[j], nu)
    gated = d2 <= CFG.tracker.gamma4
    assert np.array_equal(assoc.in_some_gate, gated.any(axis=0))
    assert np.array_equal(assoc.n_in_gate, gated.sum(axis=1))
    conf_rows = [i for i in range(T) if confirmed[i]]
    first = [(r, c) for r, c in assoc.pairs if r in conf_rows]
    assert assoc.pairs[: len(first)] == first  # confirmed first
    check_optimal(first, d2, gated, conf_rows, list(range(P)))
    left = [j for j in range(P) if j not in {c for _, c in first}]
    check_optimal(assoc.pairs[len(first) :], d2, gated, [i for i in range(T) if not confirmed[i]], left)
    for r, c in assoc.pairs:
        assert assoc.d2[(r, c)] == pytest.approx(d2[r, c], rel=1e-9)


# ------------------------------------------------------------------------------------------------ confirmer, deleter


@settings(max_examples=200, deadline=None)
@given(m=st.integers(1, 4), extra=st.integers(0, 3), k=st.integers(1, 4), hits=st.lists(st.booleans(), max_size=12))
def test_confirmer_and_deleter_follow_m_of_n_and_k_misses(m: int, extra: int, k: int, hits: list[bool]) -> None:
    """§2.5: CONFIRMED at the first scan where the window (the N scans after creation) holds M hits; dropped
    ("MN_failed") at the first scan where hits + scans left < M. §2.7: dropped ("K_misses") at the K-th
    consecutive miss. Driven as the tracker drives them: a hit counts, a miss counts and may drop."""
    N = m + extra
    cfg = CFG.with_tracker(confirm_M=m, confirm_N=N, drop_K=k)
    confirmer, deleter = MofNConfirmer(cfg.tracker), MissDeleter(cfg.tracker, cfg.limits)
    tr = track(np.zeros(6), np.eye(6), "TENTATIVE")
    got: list[tuple[str, int]] = []
    for s, hit in enumerate(hits, start=1):
        was = tr.status
        if hit:
            confirmer.hit(tr, TX, None)
        else:
            confirmer.miss(tr)
            reason = "MN_failed" if confirmer.failed(tr) else "K_misses" if deleter.deletes(tr) else None
            if reason is not None:
                got.append((reason, s))
                break
        if tr.status != was:
            got.append((tr.status, s))

    expected: list[tuple[str, int]] = []
    confirmed = False
    run = 0
    for s in range(1, len(hits) + 1):
        h = sum(hits[:s])
        run = 0 if hits[s - 1] else run + 1
        if not confirmed and h >= m:
            confirmed = True
            expected.append(("CONFIRMED", s))
        elif not confirmed and h + (N - s) < m:
            expected.append(("MN_failed", s))
            break
        elif run >= k:
            expected.append(("K_misses", s))
            break
    assert got == expected


def test_deleter_drops_the_weakest_tentative_tracks_beyond_capacity() -> None:
    cfg = CFG.with_limits(max_tentative_tracks=2)
    trs = [track(np.zeros(6), np.eye(6), "TENTATIVE", i) for i in range(1, 6)]
    for t, (hits, created) in zip(trs, [(3, 1), (2, 4), (2, 2), (4, 0), (2, 2)], strict=True):
        t.hits, t.created_scan = hits, created
    trs.append(track(np.zeros(6), np.eye(6), "CONFIRMED", 9))
    out = MissDeleter(cfg.tracker, cfg.limits).over_capacity(trs)
    assert [t.track_id for t in out] == [3, 5, 2]  # fewest hits, then oldest, then lowest id; confirmed kept


# ------------------------------------------------------------------------------------------------ swapping


def scans(n: int) -> list[BistaticScan]:
    """One target of the paper's kind (200 m/s, course 256°), one noise-free plot per 3 s scan."""
    c = 256.0 * D2R
    v = np.array([200.0 * math.sin(c), 200.0 * math.cos(c), 0.0])
    out = []
    for k in range(1, n + 1):
        t = 3.0 * (k - 1)
        z = h_b(np.concatenate([np.array([9000.0, 5000.0, 1000.0]) + v * t, v]), TX)
        out.append(scan_from_bistatic(k, round(t * NS), z[None]))
    return out


class NoAssociation(GatedAssociator):
    """An associator that gates as usual but never assigns (every track coasts; no plot is in a gate)."""

    def associate(self, tracks: list[TrackState], pred: Prediction, z: np.ndarray, R_plot: np.ndarray) -> Association:
        a = super().associate(tracks, pred, z, R_plot)
        return Association([], {}, np.zeros(len(z), dtype=bool), a.n_in_gate)


def test_components_are_declared_with_config_defaults_and_swappable() -> None:
    """The default tracker equals one given its default components explicitly; with an associator that never
    assigns, the first track is never updated and drops at its K-th miss (scan 2 + K), and every plot goes to
    initiation (a new track every second scan)."""
    feed = scans(8)
    t = CFG.tracker
    default = PclTracker(CFG)
    explicit = PclTracker(
        CFG, associator=GatedAssociator(t), confirmer=MofNConfirmer(t), deleter=MissDeleter(t, CFG.limits)
    )
    a = [r for s in feed for r in default.step(s)]
    b = [r for s in feed for r in explicit.step(s)]
    assert [r.model_dump() for r in a] == [r.model_dump() for r in b]
    assert [r.n_associated for r in a] == [0, 0, 1, 1, 1, 1, 1, 1] and a[-1].tracks[0].hits == 8

    swapped = PclTracker(CFG, associator=NoAssociation(t))
    assert isinstance(swapped.associator, NoAssociation)
    reps = [r for s in feed for r in swapped.step(s)]
    assert all(r.n_associated == 0 for r in reps)
    k_drop = 2 + t.drop_K
    first = [(r.scan_id, tr) for r in reps for tr in r.tracks if tr.track_id == 1]
    assert [s for s, _ in first] == list(range(2, k_drop + 1))
    assert all(tr.coasted and not tr.updated and tr.hits == 2 for s, tr in first if s > 2)
    assert first[-1][1].status == "DROPPED" and first[-1][1].drop_reason == "K_misses"
    assert [r.n_initiated for r in reps] == [0, 1, 0, 1, 0, 1, 0, 1]


def test_successor_and_restore_keep_given_components_and_a_new_config_rebuilds_the_defaults() -> None:
    """The next run's tracker (service ``new_run``) and a restored one keep a swapped component; assigning a
    configuration rebuilds only the components that were not given (here M/N follows the new confirm_M)."""
    t = CFG.tracker
    trk = PclTracker(CFG, associator=NoAssociation(t))
    for s in scans(4):
        trk.step(s)
    nxt = trk.successor()
    assert isinstance(nxt.associator, NoAssociation) and nxt.next_track_id == trk.next_track_id and not nxt.tracks
    back = PclTracker.restore(trk.snapshot(), associator=NoAssociation(t))
    assert isinstance(back.associator, NoAssociation) and back.snapshot() == trk.snapshot()
    trk.config = CFG.with_tracker(confirm_M=2, confirm_N=3)
    assert isinstance(trk.associator, NoAssociation) and (trk.confirmer.M, trk.confirmer.N) == (2, 3)
