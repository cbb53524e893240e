"""The initiator: new tracks by the 2/L criterion with the ring + ellipse gate (digest 003 §2.3–§2.5).

The plots that may start tracks, P0, are those in no association gate and convertible (r_b >=
``rb_min_convertible_m``), §5.5 step 5; in a clutter burst (§5.6) either none (the candidates only age) or
the ``max_plots_per_scan`` strongest by SNR (``burst_initiation: strongest_snr``).

Each plot of P0, converted by the UT to z_c(2), R_c(2), is tried as second plot against every stored first
plot (candidate) z_c(1), R_c(1) of the L-1 previous scans, tau_2 = t(2) - t(1) (at least
``min_init_interval_s``), R_min = V_min tau_2, R_max = V_max tau_2, d_12 = |z_c(2) - z_c(1)|:

    the pair passes if R_min <= d_12 <= R_max, or else if
    rho = (z_c(2) - z_m)^T (R_c(1) + R_c(2))^-1 (z_c(2) - z_m) < gamma_3 = chi^2_3(P_g),
    z_m = z_c(1) + R e_12, R = R_max (d_12 > R_max) or R_min (d_12 < R_min)

(:func:`.initiation.ring_gate_pairs`). Every passing pair starts a track from the two-plot estimate
x_b(2) = [r_b, v_b, alpha, (alpha(2) - alpha(1))/tau_2, eps, (eps(2) - eps(1))/tau_2] with P_b(2) (§2.4,
"full" adds cov(alpha, alpha_dot) = sigma_alpha(2)^2/tau_2 and likewise for eps), then

* scheme "proposed" (and "bkf_ukf" with M = 0): x_a(2), P_a(2) = UT (n = 6) of x_b(2), P_b(2) through h_a^(6);
* "bkf_ukf" with M > 0 and "bkf_only": the bistatic state itself (phase "bkf");
* "ukf_only" (§2.5 [D]): x = [z_c(2); (z_c(2) - z_c(1))/tau_2],
  P = [[R_c(2), R_c(2)/tau_2], [R_c(2)/tau_2, (R_c(1) + R_c(2))/tau_2^2]].

An IMM track starts every model from that estimate with probabilities ``imm_mu0``. Bookkeeping [D]: a
candidate that spawned a track is removed, candidates expire after L-1 scans, the unpaired plots of P0 become
candidates. The new tracks are TENTATIVE (CONFIRMED if M = 0); the tracker gives them their ids.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from shared.filters.covariance import CholeskyStats

from .config import LimitsConfig, TrackerConfig
from .filter import ConvertedPlots
from .geometry import BoolArray, FloatArray
from .initiation import bistatic_to_cartesian, ring_gate_pairs, two_plot_bistatic_estimate, ukf_only_init
from .plots import NormalisedPlots
from .state import CandidateSet, TrackState


@dataclass
class Initiation:
    """New tracks (``track_id`` still 0), the plot row that started each, and the candidates kept."""

    tracks: list[TrackState]
    plot_rows: list[int]
    candidates: CandidateSet


class Initiator(Protocol):
    """Chooses the plots that may start tracks, and starts tracks from them and the stored candidates."""

    def pool(self, plots: NormalisedPlots, in_some_gate: BoolArray, burst: bool) -> tuple[BoolArray, bool]: ...

    def initiate(
        self,
        p0: list[int],
        plots: NormalisedPlots,
        conv: ConvertedPlots,
        conv_of: dict[int, int],
        candidates: CandidateSet,
        sid: int,
        t_ns: int,
        tx: FloatArray,
        chol: CholeskyStats | None,
    ) -> Initiation: ...

    def expire(self, candidates: CandidateSet, sid: int) -> CandidateSet: ...


class TwoPlotInitiator:
    """2/L initiation with the ring + ellipse gate (module doc); ``gamma`` defaults to gamma_3."""

    def __init__(self, config: TrackerConfig, limits: LimitsConfig, gamma: float | None = None) -> None:
        self.config = config
        self.limits = limits
        self.gamma = config.gamma3 if gamma is None else gamma

    def pool(self, plots: NormalisedPlots, in_some_gate: BoolArray, burst: bool) -> tuple[BoolArray, bool]:
        """P0 before conversion (in no gate, convertible) and whether it was cut to the strongest plots."""
        pool = ~in_some_gate & ~plots.low_rb
        strongest = burst and self.config.burst_initiation == "strongest_snr"
        if strongest:
            pool = strongest_plots(plots.snr_db, pool, self.limits.max_plots_per_scan)
        return pool, strongest

    def expire(self, candidates: CandidateSet, sid: int) -> CandidateSet:
        """The candidates still within L-1 scans (a scan that initiates nothing)."""
        return candidates.take(np.flatnonzero(sid - candidates.scan_id < self.config.init_L - 1))

    def initiate(
        self,
        p0: list[int],
        plots: NormalisedPlots,
        conv: ConvertedPlots,
        conv_of: dict[int, int],
        candidates: CandidateSet,
        sid: int,
        t_ns: int,
        tx: FloatArray,
        chol: CholeskyStats | None,
    ) -> Initiation:
        trk = self.config
        allc = candidates
        age = sid - allc.scan_id
        min_dt_ns = round(self.limits.min_init_interval_s * 1e9)
        usable = np.flatnonzero(
            (age >= 1) & (age <= trk.init_L - 1) & (allc.t_ns <= t_ns - min_dt_ns) & (allc.t_ns < t_ns)
        )
        cands = allc.take(usable)  # already in (scan_id, plot_id) order
        ci_arr = pj_arr = np.zeros(0, dtype=np.int64)  # (candidate index, index into p0)
        k0 = np.array([conv_of[j] for j in p0], dtype=np.int64)
        tau = np.asarray((t_ns - cands.t_ns) * 1e-9, dtype=np.float64)
        if len(cands) and p0:
            ci_arr, pj_arr = ring_gate_pairs(
                cands.zc, cands.Rc, tau, conv.y[k0], conv.R[k0], trk.ring_vmin_mps, trk.ring_vmax_mps, self.gamma
            )
        new: list[TrackState] = []
        rows: list[int] = []
        if ci_arr.size:
            p0_arr = np.array(p0, dtype=np.int64)
            plot_rows = p0_arr[pj_arr]
            z2, s2 = plots.z[plot_rows], plots.sig[plot_rows]
            tau2 = tau[ci_arr]
            if trk.scheme == "ukf_only":
                k2 = k0[pj_arr]
                X, P = ukf_only_init(cands.zc[ci_arr], cands.Rc[ci_arr], conv.y[k2], conv.R[k2], tau2)
                phase = "ukf"
            else:
                xb, Pb = two_plot_bistatic_estimate(cands.z[ci_arr], cands.sig[ci_arr], z2, s2, tau2, trk.init_cov)
                bkf_phase = trk.scheme == "bkf_only" or (trk.scheme == "bkf_ukf" and trk.confirm_M > 0)
                if bkf_phase:
                    X, P, phase = xb, Pb, "bkf"
                else:
                    res = bistatic_to_cartesian(xb, Pb, tx, trk.transform, chol)
                    X, P, phase = res.mean, res.cov, "ukf"
            status = "CONFIRMED" if trk.confirm_M == 0 else "TENTATIVE"
            for k, j in enumerate(plot_rows.tolist()):
                tr = TrackState(track_id=0, status=status, phase=phase, x=X[k], P=P[k], t_ns=t_ns, created_scan=sid)
                if trk.motion_model == "imm" and phase == "ukf":
                    r = len(trk.imm_q_m2s4)  # every model starts from the two-plot estimate
                    tr.mu = np.array(trk.imm_mu0, dtype=np.float64)
                    tr.xm = np.repeat(X[k][None], r, axis=0)
                    tr.Pm = np.repeat(P[k][None], r, axis=0)
                new.append(tr)
                rows.append(j)
        # candidates: drop those that spawned a track and the expired ones, add the unpaired plots of P0
        spawned = np.zeros(len(allc), dtype=bool)
        spawned[usable[ci_arr]] = True
        keep = np.flatnonzero(~spawned & (sid - allc.scan_id < trk.init_L - 1) & (allc.t_ns < t_ns))
        paired = np.zeros(len(p0), dtype=bool)
        paired[pj_arr] = True
        new_rows = np.array(p0, dtype=np.int64)[~paired]
        new_k = k0[~paired]
        fresh = CandidateSet(
            [plots.ids[j] for j in new_rows.tolist()],
            np.full(new_rows.size, sid, dtype=np.int64),
            np.full(new_rows.size, t_ns, dtype=np.int64),
            plots.z[new_rows],
            plots.sig[new_rows],
            conv.y[new_k],
            conv.R[new_k],
        )
        return Initiation(new, rows, allc.take(keep).extend(fresh))


def strongest_plots(snr_db: FloatArray, pool: BoolArray, n_max: int) -> BoolArray:
    """The at most ``n_max`` plots of ``pool`` with the highest SNR (plots without SNR last; ties in plot order)."""
    idx = np.flatnonzero(pool)
    if idx.size <= n_max:
        return pool.copy()
    snr = np.where(np.isfinite(snr_db[idx]), snr_db[idx], -np.inf)
    keep = idx[np.argsort(-snr, kind="stable")[:n_max]]
    out = np.zeros_like(pool)
    out[keep] = True
    return out
