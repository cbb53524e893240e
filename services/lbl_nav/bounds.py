"""Independent reference computations for the scenario tests of digest 000 (section 4.2): the Cramér-Rao bound
of a simulated run and the exact likelihood ratio of the two mirror hypotheses, both for the model linearised
along a fixed trajectory.

Pure numpy, written from the digest (sections 1.3-1.5) and not from the estimator's modules: the state is
X = [x, y, dc, dK, dU_N, dU_E] (x East, y North), the forward step is section 1.5's Phi = M D, b, Q, the ranges
are Eq. (1) linearised at a given trajectory point (the truth, or its mirror image across the beacon line) with
the predicted travel time D*/c~ as dc's coefficient (see ``linearised_filter``), and the data are processed by a
plain forward Kalman filter from the first epoch used, with a diffuse position prior and the stationary priors
of dc, dK, dU. For a model that is linear in the state the covariance of that filter is
the posterior Cramér-Rao bound of the position given exactly those data (it does not depend on the measured
values), and its accumulated innovations give the exact Gaussian marginal likelihood of the data, so that

    ln dp = 1/2 (ln B_mirror - ln B_true) + 1/2 (A_mirror - A_true)

is the exact log posterior ratio (true over mirror hypothesis) of the linearised model with equal priors.
Compared with the estimator (section 2.4's augmented, backward processing in an EKF) this is a different
algorithm on the same model: by section 2.4's equivalence it gives the same covariance once all buffered
epochs are processed, and it has no linearisation error at the truth.

"With buffered data" = all epochs from the first buffered one (t_{-N}); "without" = from the launch epoch. The
epoch data (integrated DR, ranges, truth) come from a ``simulation.SimRun``'s messages and arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from schemas import BeaconRange, BeaconTable, Current, Heading, SpeedLog
from shared.filters import kalman

from .models import ErrorModel
from .simulation import ScenarioSpec, SimRun

F64 = NDArray[np.float64]
#: variance of the diffuse position prior (m^2): 100 km standard deviation
DIFFUSE_M2 = 1e10


@dataclass(frozen=True)
class NoiseModel(ErrorModel):
    """The digest's error model (section 1) the simulator draws from, with the nominal sound speed."""

    c_mps: float = 1500.0

    @classmethod
    def of(cls, spec: ScenarioSpec) -> NoiseModel:
        """The model the simulator draws from (= the filter's configuration in S1-S3)."""
        return cls(
            spec.sigma_delta_m,
            spec.sigma_v_m,
            spec.sigma_dc_mps,
            spec.sigma_dV_mps,
            math.radians(spec.sigma_dK_deg),
            spec.sigma_dU_mps,
            spec.tau_dK_s,
            spec.tau_dU_s,
            spec.c_nominal_mps,
        )


@dataclass(frozen=True)
class EpochData:
    """Per epoch k (index into the run, the interval (t_{k-1}, t_k]): integrated DR and the ranges.

    ``ve_dt``/``vn_dt``: log velocity on the measured heading times dt; ``ue_dt``/``un_dt``: known current times
    dt; ``ranges[k]``: (beacon x, y, z, measured range) rows; ``xy_true``: the true horizontal position."""

    dt: F64
    ve_dt: F64
    vn_dt: F64
    ue_dt: F64
    un_dt: F64
    z: F64
    ranges: list[list[tuple[float, float, float, float]]]
    xy_true: F64
    beacons: dict[str, tuple[float, float, float]]
    i0: int


def epoch_data(run: SimRun) -> EpochData:
    """Collect the run's inputs per epoch from its messages (1 Hz DR samples stamped at the epoch ends)."""
    n = run.t_s.size
    vf = np.zeros(n)
    vs = np.zeros(n)
    K = np.zeros(n)
    un = ue = 0.0
    beacons: dict[str, tuple[float, float, float]] = {}
    ranges: list[list[tuple[float, float, float, float]]] = [[] for _ in range(n)]
    for m in run.messages:
        if isinstance(m, BeaconTable):
            beacons = {b.beacon_id: (b.x_east_m, b.y_north_m, b.depth_m) for b in m.beacons}
        elif isinstance(m, Current):
            un, ue = m.u_north_mps, m.u_east_mps
        elif isinstance(m, SpeedLog):
            k = run.index_of(m.header.stamp_ns)
            vf[k], vs[k] = m.v_forward_mps, m.v_starboard_mps
        elif isinstance(m, Heading):
            K[run.index_of(m.header.stamp_ns)] = m.heading_rad
        elif isinstance(m, BeaconRange):
            k = run.index_of(m.header.stamp_ns)
            value = m.range_m if m.range_m is not None else float(m.travel_time_s or 0.0) * run.spec.c_nominal_mps
            ranges[k].append((*beacons[m.beacon_id], float(value)))
    dt = np.full(n, run.spec.dt_s)
    ve = (vf * np.sin(K) + vs * np.cos(K)) * dt
    vn = (vf * np.cos(K) - vs * np.sin(K)) * dt
    z = np.full(n, run.spec.auv_depth_m)
    xy = np.column_stack([run.x_m, run.y_m])
    return EpochData(dt, ve, vn, ue * dt, un * dt, z, ranges, xy, beacons, run.i0)


def mirror_xy(xy: F64, b1: tuple[float, float], b2: tuple[float, float]) -> F64:
    """Reflection of points (rows x, y) across the line through the two beacons' horizontal positions."""
    p = np.asarray(b1, dtype=np.float64)
    u = np.asarray(b2, dtype=np.float64) - p
    u /= np.hypot(*u)
    d = np.asarray(xy, dtype=np.float64) - p
    along = d @ u
    return p + 2.0 * np.outer(along, u) - d


@dataclass
class LinearisedRun:
    """Output of ``linearised_filter``: per processed epoch (k_first..k_last) the state, covariance and the
    accumulated A = sum nu^T S^-1 nu and ln B = sum ln det S."""

    k: NDArray[np.int64]
    X: F64  # (n, 6)
    P: F64  # (n, 6, 6)
    A: F64
    lnB: F64  # noqa: N815

    def pos_var(self) -> F64:
        """Trace of the horizontal position covariance per epoch (m^2)."""
        return self.P[:, 0, 0] + self.P[:, 1, 1]


def _markov(dt: float, tau: float, sigma: float) -> tuple[float, float]:
    if sigma == 0.0 or not math.isfinite(tau):
        return 1.0, 0.0
    a = math.exp(-dt / tau)
    return a, sigma * sigma * (1.0 - a * a)


def linearised_filter(
    data: EpochData,
    noise: NoiseModel,
    k_first: int,
    k_last: int | None = None,
    lin_xy: F64 | None = None,
    dK_lin: F64 | None = None,
    pos_prior_var_m2: float = DIFFUSE_M2,
    dc_coefficient: str = "predicted",
) -> LinearisedRun:
    """Forward Kalman filter over epochs k_first..k_last of the model linearised at the trajectory ``lin_xy``
    (default: the truth) for the ranges and at the heading correction ``dK_lin`` (default 0, i.e. about the
    measured heading as the paper does) for the DR. Prior at k_first: position about ``lin_xy`` with variance
    ``pos_prior_var_m2`` (default diffuse), dc, dK, dU zero-mean with their stationary variances. DR of epoch
    k_first is not used (the prior is at its end). ``dc_coefficient``: the travel time multiplying dc in Eq. (1),
    "predicted" = D*/c~ at the linearisation point (default) or "measured" = y/c~ (the measured travel time;
    it carries the range's own noise, which correlates the gain with the innovation and biases the dc
    estimate upwards; kept to show that effect)."""
    n_ep = data.dt.size
    k_last = n_ep - 1 if k_last is None else k_last
    lin = data.xy_true if lin_xy is None else lin_xy
    X = np.array([lin[k_first, 0], lin[k_first, 1], 0.0, 0.0, 0.0, 0.0])
    P = np.diag(
        [pos_prior_var_m2, pos_prior_var_m2, noise.sigma_dc_mps**2, noise.sigma_dK_rad**2, *[noise.sigma_dU_mps**2] * 2]
    )
    ks = np.arange(k_first, k_last + 1)
    Xs = np.empty((ks.size, 6))
    Ps = np.empty((ks.size, 6, 6))
    A_acc = np.empty(ks.size)
    lnB_acc = np.empty(ks.size)
    A = lnB = 0.0
    for j, k in enumerate(ks):
        if k > k_first:
            X, P = _predict(data, noise, int(k), X, P, 0.0 if dK_lin is None else float(dK_lin[k]))
        rows = data.ranges[k]
        if rows:
            X, P, a, ld = _update(rows, float(data.z[k]), lin[k], noise, X, P, dc_coefficient == "measured")
            A += a
            lnB += ld
        Xs[j], Ps[j], A_acc[j], lnB_acc[j] = X, P, A, lnB
    return LinearisedRun(ks, Xs, Ps, A_acc, lnB_acc)


def _predict(data: EpochData, noise: NoiseModel, k: int, X: F64, P: F64, dk: float) -> tuple[F64, F64]:
    """Section 1.5: Phi = M D, b, Q = M diag(0, 0, 0, qK, qU, qU) M^T + diag(w2, w2, 0, 0, 0, 0)."""
    dt = float(data.dt[k])
    aK, qK = _markov(dt, noise.tau_dK_s, noise.sigma_dK_rad)
    aU, qU = _markov(dt, noise.tau_dU_s, noise.sigma_dU_mps)
    # DR displacement rotated by the linearisation heading correction dk; its derivative wrt dK there
    c, s = math.cos(dk), math.sin(dk)
    ve = float(data.ve_dt[k]) * c + float(data.vn_dt[k]) * s
    vn = float(data.vn_dt[k]) * c - float(data.ve_dt[k]) * s
    M = np.eye(6)
    M[0, 3], M[0, 5] = vn, dt
    M[1, 3], M[1, 4] = -ve, dt
    D = np.diag([1.0, 1.0, 1.0, aK, aU, aU])
    Phi = M @ D
    b = np.array([ve - vn * dk + float(data.ue_dt[k]), vn + ve * dk + float(data.un_dt[k]), 0.0, 0.0, 0.0, 0.0])
    w2 = noise.sigma_dV_mps**2 * dt
    Q = M @ np.diag([0.0, 0.0, 0.0, qK, qU, qU]) @ M.T + np.diag([w2, w2, 0.0, 0.0, 0.0, 0.0])
    return Phi @ X + b, Phi @ P @ Phi.T + Q


def _update(
    rows: list[tuple[float, float, float, float]],
    z: float,
    p_lin: F64,
    noise: NoiseModel,
    X: F64,
    P: F64,
    measured_T: bool,
) -> tuple[F64, F64, float, float]:
    """Eq. (1) linearised at (p_lin, dc = 0): y ~ D* + g (p - p*) + T dc, T = D*/c~ (or y/c~ if measured_T);
    R = sd^2 1 1^T + sv^2 I."""
    m = len(rows)
    H = np.zeros((m, 6))
    nu = np.empty(m)
    for r, (bx, by, bz, y) in enumerate(rows):
        ex, ey, ez = p_lin[0] - bx, p_lin[1] - by, z - bz
        D = math.sqrt(ex * ex + ey * ey + ez * ez)
        H[r, 0], H[r, 1], H[r, 2] = ex / D, ey / D, (y if measured_T else D) / noise.c_mps
        nu[r] = y - (D + H[r, 0] * (X[0] - p_lin[0]) + H[r, 1] * (X[1] - p_lin[1]) + H[r, 2] * X[2])
    R = noise.sigma_delta_m**2 * np.ones((m, m)) + noise.sigma_v_m**2 * np.eye(m)
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    _, logdet = np.linalg.slogdet(S)
    return X + K @ nu, kalman.joseph(P, K, H, R), float(nu @ np.linalg.solve(S, nu)), float(logdet)


# ---- what the scenario tests use ------------------------------------------------------------------------------
def position_bound(run: SimRun, noise: NoiseModel, buffered: bool) -> F64:
    """Cramér-Rao bound of the horizontal position error variance (m^2, trace of the 2x2 block) at every epoch
    from launch on, from the data with (from t_{-N}) or without (from t_0) the buffered epochs."""
    data = epoch_data(run)
    k0 = data.i0
    k_first = _first_range(data) if buffered else k0
    out = linearised_filter(data, noise, k_first)
    return out.pos_var()[k0 - k_first :]


def position_bound_partial(run: SimRun, noise: NoiseModel, k: int, n_buffered: int) -> float:
    """The bound at epoch k (index into the run) when only the last ``n_buffered`` buffered epochs have been
    processed (section 2.4's schedule: n_buffered = min(dN0 + i dN, N) at i = k - i0)."""
    data = epoch_data(run)
    k_first = max(_first_range(data), data.i0 - n_buffered)
    return float(linearised_filter(data, noise, k_first, k).pos_var()[-1])


def log_ratio_true_over_mirror(run: SimRun, noise: NoiseModel, buffered: bool, dK_lin: F64 | None = None) -> F64:
    """Exact ln dp (true hypothesis over its mirror image) of the linearised model at every epoch from launch on;
    ranges linearised at the truth and at its mirror image across the beacon line."""
    data = epoch_data(run)
    k0 = data.i0
    k_first = _first_range(data) if buffered else k0
    names = sorted(data.beacons)
    b1, b2 = data.beacons[names[0]], data.beacons[names[1]]
    mir = mirror_xy(data.xy_true, b1[:2], b2[:2])
    t = linearised_filter(data, noise, k_first, dK_lin=dK_lin)
    m = linearised_filter(data, noise, k_first, lin_xy=mir, dK_lin=dK_lin)
    lr = 0.5 * (m.lnB - t.lnB) + 0.5 * (m.A - t.A)
    return lr[k0 - k_first :]


def _first_range(data: EpochData) -> int:
    return next(k for k, rows in enumerate(data.ranges) if rows)


def mirror_heading_correction(run: SimRun, data: EpochData) -> F64:
    """dK the mirror hypothesis needs at every epoch: the mirror of the true track has heading 2 alpha - K_true
    (alpha the beacon line's azimuth), so dK' = 2 alpha - K_true - K_measured (true heading = measured + dK)."""
    names = sorted(data.beacons)
    b1, b2 = data.beacons[names[0]], data.beacons[names[1]]
    alpha = math.atan2(b2[0] - b1[0], b2[1] - b1[1])
    k_measured = run.heading_true_rad - run.dK_rad
    return np.asarray(2.0 * alpha - run.heading_true_rad - k_measured, dtype=np.float64)


def exact_log_ratio_at(
    run: SimRun, noise: NoiseModel, k_last: int, n_buffered: int | None = None, heading_at_truth: bool = True
) -> float:
    """Exact ln dp (true over mirror) of the data of epochs k_first..k_last, k_first = the first range (all
    buffered epochs, ``n_buffered`` None) or the launch epoch minus ``n_buffered`` (what the estimator had
    processed; section 2.4's schedule). The ranges are linearised at the truth and at its mirror image, the heading
    terms at the true dK and at the dK the mirror needs (``heading_at_truth``; False: about 0, as the paper's EKF),
    so that the only approximation left is the range curvature over the posterior width."""
    data = epoch_data(run)
    first = _first_range(data)
    k_first = first if n_buffered is None else max(first, data.i0 - n_buffered)
    names = sorted(data.beacons)
    b1, b2 = data.beacons[names[0]], data.beacons[names[1]]
    mir = mirror_xy(data.xy_true, b1[:2], b2[:2])
    dk_t = run.dK_rad if heading_at_truth else None
    dk_m = mirror_heading_correction(run, data) if heading_at_truth else None
    t = linearised_filter(data, noise, k_first, k_last, dK_lin=dk_t)
    m = linearised_filter(data, noise, k_first, k_last, lin_xy=mir, dK_lin=dk_m)
    return float(0.5 * (m.lnB[-1] - t.lnB[-1]) + 0.5 * (m.A[-1] - t.A[-1]))
