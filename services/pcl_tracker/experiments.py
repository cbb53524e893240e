"""The paper's single-target filter loop, vectorised over Monte-Carlo runs (digest 003 §3.4, §4.2, §4.3).

This is the "single-track filter loop, no re-initiation" of the digest's statistical tests: the track is
initialised from the plots of scans 1 and 2 and then predicted, gated (optionally) and updated scan by scan
with the same batched functions the core uses (:mod:`.filter`, :mod:`.initiation`), for all runs at once.
A test checks that it reproduces :class:`~services.pcl_tracker.core.PclTracker` to rounding.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from shared.filters import kalman
from shared.filters.unscented import TransformResult

from .config import PclTrackerConfig
from .filter import (
    bistatic_image,
    bkf_measurement,
    bkf_predict,
    bkf_update,
    convert_plots,
    innovation,
    kf_position_update,
    predict,
    ukf_bistatic_update,
)
from .geometry import BoolArray, FloatArray
from .imm import bistatic_loglik, combine, combine_measurements, imm_position_update, imm_predict
from .initiation import bistatic_to_cartesian, two_plot_bistatic_estimate, ukf_only_init
from .models import plot_covariance


@dataclass
class LoopResult:
    """Per run and scan: estimates and the figures the acceptance tests need (NaN where undefined)."""

    x: FloatArray  # (R, T, 6) Cartesian estimate x_a(k|k) (UT image of x_b while in the BKF phase)
    P: FloatArray  # (R, T, 6, 6)
    z_out: FloatArray  # (R, T, 4) bistatic image of x(k|k) [r_b, a, e, v_b] (if requested)
    nis: FloatArray  # (R, T) d^2 of the true plot against the prediction
    in_gate: BoolArray  # (R, T) the true plot was inside the gate (always True without gating)
    alive: BoolArray  # (R, T) the track exists after scan k
    drop_index: NDArray[np.int64]  # (R,) scan index of the drop, -1 if never dropped


def _sub(res: TransformResult, idx: NDArray[np.int64]) -> TransformResult:
    return TransformResult(res.mean[idx], res.cov[idx], res.cross[idx])


def run_single_target(
    z: FloatArray,
    sig: FloatArray,
    times_s: FloatArray,
    cfg: PclTrackerConfig,
    *,
    gating: bool = False,
    bistatic_output: bool = False,
) -> LoopResult:
    """Run the configured scheme on plots z (R, T, 4) with sigmas sig (4,) (m, rad, rad, m/s).

    ``gating``: a true plot outside the 4-D gate is a miss (coast); K consecutive misses drop the track,
    which then stays dead (no re-initiation). Without gating every plot is used (digest §3.4 setup).
    """
    trk = cfg.tracker
    tx = np.asarray(cfg.geometry.tx_position_enu_m, dtype=np.float64)
    R_runs, T, _ = z.shape
    gamma4 = trk.gamma4
    kind = trk.transform
    x_out = np.full((R_runs, T, 6), np.nan)
    P_out = np.full((R_runs, T, 6, 6), np.nan)
    z_out = np.full((R_runs, T, 4), np.nan)
    nis = np.full((R_runs, T), np.nan)
    in_gate = np.ones((R_runs, T), dtype=bool)
    alive = np.zeros((R_runs, T), dtype=bool)
    drop_index = np.full(R_runs, -1, dtype=np.int64)
    sigs = np.broadcast_to(sig, (R_runs, 4)).copy()
    R_plot = plot_covariance(sigs)

    # ---- initialisation from scans 1 and 2 (index 0 and 1)
    tau2 = np.full(R_runs, times_s[1] - times_s[0])
    bkf_phase = trk.scheme == "bkf_only" or (trk.scheme == "bkf_ukf" and trk.confirm_M > 0)
    if trk.scheme == "ukf_only":
        c1 = convert_plots(z[:, 0, :3], sigs[:, :3], tx, kind)
        c2 = convert_plots(z[:, 1, :3], sigs[:, :3], tx, kind)
        X, P = ukf_only_init(c1.y, c1.R, c2.y, c2.R, tau2)
    else:
        X, P = two_plot_bistatic_estimate(z[:, 0], sigs, z[:, 1], sigs, tau2, trk.init_cov)
        if not bkf_phase:
            res = bistatic_to_cartesian(X, P, tx, kind)
            X, P = res.mean, res.cov
    phase_bkf = np.full(R_runs, bkf_phase)
    imm = trk.motion_model == "imm"
    if imm:  # every model starts from the two-plot estimate (as the core does)
        models = trk.imm_models
        MU = np.broadcast_to(np.array(models.mu0), (R_runs, models.r)).copy()
        XM = np.repeat(X[:, None], models.r, axis=1)
        PM = np.repeat(P[:, None], models.r, axis=1)
    live = np.ones(R_runs, dtype=bool)
    misses = np.zeros(R_runs, dtype=np.int64)
    hits_after = np.zeros(R_runs, dtype=np.int64)

    def record(k: int) -> None:
        alive[:, k] = live
        u = np.flatnonzero(live & ~phase_bkf)
        b = np.flatnonzero(live & phase_bkf)
        x_out[u, k], P_out[u, k] = X[u], P[u]
        if b.size:
            ca = bistatic_to_cartesian(X[b], P[b], tx, kind)
            x_out[b, k], P_out[b, k] = ca.mean, ca.cov
        if bistatic_output:
            if u.size:
                z_out[u, k] = bistatic_image(X[u], P[u], tx, kind).mean
            if b.size:
                z_out[b, k] = bkf_measurement(X[b], P[b]).mean

    record(1)
    for k in range(2, T):
        tau = np.full(R_runs, times_s[k] - times_s[k - 1])
        u = np.flatnonzero(live & ~phase_bkf)
        b = np.flatnonzero(live & phase_bkf)
        pred_u: TransformResult | None = None
        if u.size and imm:
            MU[u], XM[u], PM[u] = imm_predict(MU[u], XM[u], PM[u], tau[u], models)
            X[u], P[u] = combine(MU[u], XM[u], PM[u])
            ZM = bistatic_image(XM[u].reshape(-1, 6), PM[u].reshape(-1, 6, 6), tx, kind)
            zm, Sm = ZM.mean.reshape(u.size, models.r, 4), ZM.cov.reshape(u.size, models.r, 4, 4)
            pred_u = TransformResult(*combine_measurements(MU[u], zm, Sm), np.zeros((u.size, 0, 0)))
        elif u.size:
            X[u], P[u] = predict(X[u], P[u], tau[u], trk.q_accel_var_m2s4)
            pred_u = bistatic_image(X[u], P[u], tx, kind)
        if b.size:
            X[b], P[b] = bkf_predict(X[b], P[b], tau[b], trk.bkf_q_r_m2s4, trk.bkf_q_ang_rad2s4)
            pred_b = bkf_measurement(X[b], P[b])
        for idx, pred in ((u, pred_u), (b, pred_b if b.size else None)):
            if pred is None or idx.size == 0:
                continue
            nu = innovation(z[idx, k], pred.mean)
            d2 = kalman.nis(nu, pred.cov + R_plot[idx])
            nis[idx, k] = d2
            if gating and imm and pred is pred_u:
                # the core's IMM gate: the union of the models' gates
                nu_m = innovation(z[idx, k][:, None, :], zm)
                in_gate[idx, k] = (kalman.nis(nu_m, Sm + R_plot[idx][:, None]) <= gamma4).any(axis=1)
            elif gating:
                in_gate[idx, k] = d2 <= gamma4
        # update runs whose plot is in the gate
        uu = u[in_gate[u, k]] if u.size else u
        if uu.size and pred_u is not None:
            pos = np.searchsorted(u, uu)
            if imm:
                conv = convert_plots(z[uu, k, :3], sigs[uu, :3], tx, kind)
                ok = conv.valid & (z[uu, k, 0] >= cfg.limits.rb_min_convertible_m)
                w = uu[ok]
                if w.size:
                    ll = None
                    if trk.imm_likelihood == "bistatic":
                        pw = pos[ok]
                        ll = bistatic_loglik(z[w, k], zm[pw], Sm[pw], R_plot[w])
                    MU[w], XM[w], PM[w] = imm_position_update(MU[w], XM[w], PM[w], conv.y[ok], conv.R[ok], ll)
                    X[w], P[w] = combine(MU[w], XM[w], PM[w])
            elif trk.measurement_model == "converted_position":
                conv = convert_plots(z[uu, k, :3], sigs[uu, :3], tx, kind)
                ok = conv.valid & (z[uu, k, 0] >= cfg.limits.rb_min_convertible_m)
                X_new, P_new, _ = kf_position_update(X[uu], P[uu], conv.y, conv.R)
                X[uu] = np.where(ok[:, None], X_new, X[uu])
                P[uu] = np.where(ok[:, None, None], P_new, P[uu])
            else:
                X[uu], P[uu] = ukf_bistatic_update(X[uu], P[uu], _sub(pred_u, pos), z[uu, k], R_plot[uu])
        bb = b[in_gate[b, k]] if b.size else b
        if bb.size:
            X[bb], P[bb] = bkf_update(X[bb], P[bb], z[bb, k], R_plot[bb])
        # bookkeeping: misses, drops, BKF -> UKF handover at confirmation
        hit = live & in_gate[:, k]
        misses = np.where(hit, 0, misses + live)
        hits_after = hits_after + hit
        dropped = live & (misses >= trk.drop_K)
        drop_index[dropped] = k
        live = live & ~dropped
        if trk.scheme == "bkf_ukf":
            hand = np.flatnonzero(live & phase_bkf & (hits_after >= trk.confirm_M))
            if hand.size:
                res = bistatic_to_cartesian(X[hand], P[hand], tx, kind)
                X[hand], P[hand] = res.mean, res.cov
                phase_bkf[hand] = False
        record(k)
    return LoopResult(x_out, P_out, z_out, nis, in_gate, alive, drop_index)


def rmse_over_runs(err: FloatArray, mask: BoolArray | None = None) -> FloatArray:
    """sqrt(E ||e||^2) over runs (axis 0) for errors (R, T, d); runs outside ``mask`` (R, T) are excluded."""
    sq = np.sum(err**2, axis=-1)
    ok = np.isfinite(sq) if mask is None else (mask & np.isfinite(sq))
    n = ok.sum(axis=0)
    total = np.where(ok, sq, 0.0).sum(axis=0)
    return np.where(n > 0, np.sqrt(total / np.maximum(n, 1)), np.nan)
