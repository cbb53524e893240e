"""The particle filter's correction of one cycle (digest §4.4 steps 3-7).

Weights (steps 3-5), with e_n = d - h(X_n) (each particle compensating delta_j with its own DR error means,
delta_j - G_j m_n, whose shared covariance P_E adds H_e P_E H_e^T to R, H_e = -H_j G_j):

    p_n <- p_n [(1 - eps) exp(-e_n^T R^-1 e_n / 2) + eps exp(-outlier / 2)],   then normalised

(after a rescue e_n <- T e_n and R <- T R T^T). A failed normalisation keeps the weights (WEIGHT_FAILURE); if no
particle comes within the robust floor (min_n e_n^T R^-1 e_n > outlier) the prior weights are restored
(NO_OVERLAP): otherwise the mixture floor would report an update that did nothing.

Posterior (steps 6-7): if too few particles carry the posterior (N_eff < f_deg N) they are regenerated from its
linear-Gaussian view (:meth:`PfUpdater.regenerate`); the estimate x_hat, P_hat by Eqs. (6)-(7) (or the MAP
particle), then systematic resampling with roughening when N_eff < f N.
"""

from __future__ import annotations

import numpy as np

from shared.filters.covariance import is_positive_definite, symmetrize

from .config import RdNavConfig
from .cycle import CycleOutcome
from .gate import Innovation, Prior
from .geometry import F64
from .pf import ParticleFilter


class PfUpdater:
    """Weight update, regeneration and the posterior estimate of the particle filter."""

    def __init__(self, cfg: RdNavConfig, pf: ParticleFilter, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self.pf = pf
        self.rng = rng

    def weight(self, prior: Prior, inn: Innovation, out: CycleOutcome) -> None:
        """Steps 3-5 (module docstring); sets ``out.reject`` to WEIGHT_FAILURE or NO_OVERLAP if so."""
        cfg, pf, cd = self.cfg, self.pf, prior.cd
        prior_w = pf.w
        Rw = inn.R
        if inn.He is not None:  # each particle compensates with its mean DR errors; their shared spread adds to R
            Rw = inn.R + inn.He @ pf.PE @ inn.He.T
        Rinv = np.linalg.inv(Rw if out.T is None else out.T @ Rw @ out.T.T)
        ok, m2_min = pf.weight(
            cd.d,
            Rinv,
            cd.leader,
            cd.followers,
            prior.delta_for_update,
            cd.depth,
            cd.zj,
            cfg.epsilon,
            cfg.outlier_m2,
            out.T,
            prior.G,
        )
        if not ok:
            out.reject = "WEIGHT_FAILURE"
        elif m2_min > cfg.outlier_m2:  # no particle near the measurement: the update did nothing
            pf.w = prior_w
            out.reject = "NO_OVERLAP"

    def regenerate_if_degenerate(self, gauss: tuple[F64, F64, F64, F64, F64] | None, out: CycleOutcome) -> None:
        """Regenerate a used cycle's cloud if N_eff < ``degenerate_neff_fraction`` N (e.g. the first cycle after the
        R0 disc) and its linear-Gaussian view is known (not after a rescue)."""
        n_min = self.cfg.degenerate_neff_fraction * self.cfg.n_particles
        if out.event == "USED" and gauss is not None and self.pf.n_eff() < n_min:
            self.regenerate(*gauss)
            out.flags.append("REGENERATED")

    def regenerate(self, z: F64, C: F64, H: F64, e: F64, S: F64) -> None:
        """Resample, then draw the positions from the Gaussian posterior of the prior cloud's moments and this
        cycle's linearised measurement: K = C H^T S^-1, z+ = z + K e, C+ = C - K S K^T ([E]). A cloud much wider
        than one cycle's likelihood (the R0 = 10 m disc against ~0.5 m) leaves a handful of particles with weight,
        whose spread says nothing of the posterior's (nor do their few DR-error means); this keeps its covariance,
        the DR errors' included (their mean given each drawn position, and the conditional covariance)."""
        pf = self.pf
        K = np.linalg.solve(S, H @ C).T
        zp = z + K @ e
        Cp = C - K @ S @ K.T
        Pxx = symmetrize(Cp[:2, :2])
        if not (np.isfinite(zp).all() and is_positive_definite(Pxx)):
            return
        pf.resample(0.0)
        pf.X = zp[:2][None, :] + self.rng.standard_normal(pf.X.shape) @ np.linalg.cholesky(Pxx).T
        if zp.size > 2:  # DR errors: their mean given each position, and the conditional covariance (shared)
            B = np.linalg.solve(Pxx, Cp[:2, 2:]).T  # C_ex C_xx^-1
            pf.E = zp[2:][None, :] + (pf.X - zp[:2][None, :]) @ B.T
            PE = Cp[2:, 2:] - B @ Cp[:2, 2:]
            pf.PE = symmetrize(PE)

    def posterior(self, out: CycleOutcome, fallback_x: F64, error_cov: F64 | None) -> tuple[F64, F64, float]:
        """Estimate (Eqs. 6-7, or MAP) before resampling, then resample a used cycle's cloud if N_eff < f N.
        A non-finite cloud (never expected) is re-seeded N(x_hat or ``fallback_x``, 100 I) (PF_RESET).
        Returns (x_hat, P_hat, N_eff)."""
        cfg, pf = self.cfg, self.pf
        x_hat, P_hat = pf.estimate()
        if cfg.estimate == "map" and out.event == "USED":
            m = pf.map_estimate(cfg.map_weight_threshold)
            if m is not None:
                x_hat = m
        n_eff = pf.n_eff()
        if out.event == "USED" and n_eff < cfg.resample_fraction * cfg.n_particles:
            pf.resample(cfg.roughening_m, cfg.roughening_shrink)
        if not pf.finite():  # never expected; keep the state valid if it happens
            pf.init_gaussian(x_hat if np.isfinite(x_hat).all() else fallback_x, np.eye(2) * 100.0, error_cov)
            out.flags.append("PF_RESET")
        return x_hat, P_hat, n_eff
