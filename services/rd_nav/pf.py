"""The paper's particle filter (digest §4.4, Fig. 4), vectorised over particles with numpy.

State: N particles X_n = (x_n, y_n) (north, east, m) with weights p_n. Steps: initialise in a disc, predict with
the DR displacement plus diffusion (Eq. 5), robust Gaussian weight update on the range differences, normalise,
systematic resampling + roughening when N_eff < f*N, estimate by Eq. (6)-(7).

With the DR error model (:mod:`services.rd_nav.drift`) the filter is *marginalised* (Rao-Blackwellised; Schoen,
Gustafsson & Nordlund, IEEE TSP 53(7), 2005): the DR error states E = (speed bias, heading error, scale error) enter
the position dynamics linearly, X_b = X_a + dX - G' E_a + v (G' = G diag((1 + a)/2): the states' mean over the step),
E_b = A E_a + w, so each particle keeps only the *mean* m_n of E given its own position trajectory, and every
particle shares one covariance P_E (the Riccati recursion does not depend on the particle). Per step:

    N  = G' P_E G'^T + Q_v              X_n,b ~ N(X_n,a + dX - G' m_n, N)                  (sample the position)
    L  = -P_E G'^T N^-1                 m_n <- A (m_n + L (X_n,b - X_n,a - dX + G' m_n))   (what it says of E)
    P_E <- A (P_E - L N L^T) A + W

Only the 2-D position is sampled, so N = 300 particles do as well as N = 1000 (T-NOM-7) with three more states.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.filters.covariance import symmetrize
from shared.filters.resampling import effective_sample_size, systematic_resample

from .drift import DriftStep
from .geometry import F64, predict_d


@dataclass(frozen=True)
class PfUpdate:
    """What one weight update did."""

    ok: bool  # False: weights were non-finite or all zero; the previous weights were kept
    n_eff_before: float
    resampled: bool


class ParticleFilter:
    """N x 2 particle cloud with weights; every array operation is float64."""

    def __init__(self, n: int, rng: np.random.Generator) -> None:
        self.n = n
        self.rng = rng
        self.X: F64 = np.zeros((n, 2))
        self.E: F64 = np.zeros((n, 3))  # mean of the DR error states given each particle's trajectory (drift.STATES)
        self.PE: F64 = np.zeros((3, 3))  # their covariance, shared by every particle
        self.w: F64 = np.full(n, 1.0 / n)

    # ----- initialisation ---------------------------------------------------------------------
    def init_disc(self, center: F64, radius_m: float, error_cov: F64 | None = None) -> None:
        """Uniform in a disc of radius R0 around the start point, p_n = 1/N (§4.4 step 1); DR error states at their
        stationary distribution (mean 0, covariance ``error_cov``; None: none)."""
        r = radius_m * np.sqrt(self.rng.random(self.n))
        a = self.rng.random(self.n) * (2.0 * math.pi)
        self.X = np.column_stack([center[0] + r * np.cos(a), center[1] + r * np.sin(a)])
        self.w = np.full(self.n, 1.0 / self.n)
        self._init_errors(error_cov)

    def init_gaussian(self, mean: F64, cov: F64, error_cov: F64 | None = None) -> None:
        """Re-seed as N(mean, cov) (§4.4 step 8); DR error states at their stationary distribution."""
        L = np.linalg.cholesky(symmetrize(cov))
        self.X = mean[None, :] + self.rng.standard_normal((self.n, 2)) @ L.T
        self.w = np.full(self.n, 1.0 / self.n)
        self._init_errors(error_cov)

    def _init_errors(self, error_cov: F64 | None) -> None:
        self.E = np.zeros((self.n, 3))
        self.PE = np.zeros((3, 3)) if error_cov is None else np.array(error_cov, dtype=np.float64)

    # ----- prediction -------------------------------------------------------------------------
    def predict(self, dX: F64, q_sigma_m: float) -> None:
        """Eq. (5) for every particle plus diffusion N(0, q^2 I)."""
        self.X += dX[None, :]
        if q_sigma_m > 0.0:
            self.X += self.rng.normal(0.0, q_sigma_m, self.X.shape)

    def predict_drift(self, dX: F64, step: DriftStep) -> None:
        """Eq. (5) with the DR errors marginalised (module docstring)."""
        Gp, Qv = self.step_maps(step)
        Nc = Gp @ self.PE @ Gp.T + Qv
        Nc = symmetrize(Nc) + 1e-12 * np.eye(2)
        nu = self.rng.standard_normal(self.X.shape) @ np.linalg.cholesky(Nc).T  # X_b - E[X_b | m_n]
        self.X += dX[None, :] - self.E @ Gp.T + nu
        L = -self.PE @ Gp.T @ np.linalg.inv(Nc)  # (3, 2)
        A = np.diag(step.a)
        self.E = (self.E + nu @ L.T) * step.a[None, :]
        P = A @ (self.PE - L @ Nc @ L.T) @ A + np.diag(step.w_sd**2)
        self.PE = symmetrize(P)

    @staticmethod
    def step_maps(step: DriftStep) -> tuple[F64, F64]:
        """G' (the states' mean over the step) and the position noise Q_v (white + the states' change within it)."""
        Gp = step.G * (0.5 * (1.0 + step.a))[None, :]
        Qv = step.Q_white + 0.25 * step.G @ np.diag(step.w_sd**2) @ step.G.T
        return Gp, symmetrize(Qv)

    def predicted(self, dX: F64, G: F64) -> F64:
        """Where the particles would be after a DR displacement dX with their current error means (no noise)."""
        return self.X + dX[None, :] - self.E @ G.T

    # ----- estimate ---------------------------------------------------------------------------
    def estimate(self) -> tuple[F64, F64]:
        """Weighted mean x (Eq. 6) and cloud covariance P (the paper's Q_k, Eq. 7), symmetrised."""
        m = self.w @ self.X
        D = self.X - m[None, :]
        P = (D.T * self.w) @ D
        return m, symmetrize(P)

    def map_estimate(self, threshold: float) -> F64 | None:
        """The maximum-weight particle if its weight exceeds the threshold (§4.4 step 7)."""
        k = int(np.argmax(self.w))
        return self.X[k].copy() if self.w[k] > threshold else None

    def n_eff(self) -> float:
        return effective_sample_size(self.w)

    # ----- correction -------------------------------------------------------------------------
    def weight(
        self,
        d: F64,
        Rinv: F64,
        leader: F64,
        followers: F64,
        delta: F64,
        z1: float,
        zj: F64,
        epsilon: float,
        outlier_m2: float,
        T: F64 | None = None,
        G: F64 | None = None,
    ) -> tuple[bool, float]:
        """p_n <- p_n [(1-eps) exp(-e^T R^-1 e / 2) + eps exp(-outlier/2)], normalised (§4.4 steps 3-5).

        With ``T`` the residuals are transformed first (e <- T e) and ``Rinv`` is (T R T^T)^-1. With ``G``
        (M, 2, 3) each particle corrects the DR motion compensation by its own DR errors: delta_j - G_j E_n.
        Returns (ok, smallest m^2 over the particles); ok is False (weights kept) if the sum is not finite/zero.
        """
        if G is not None:
            delta = delta[None, :, :] - np.einsum("mij,nj->nmi", G, self.E)
        e = d[None, :] - predict_d(self.X, leader, followers, delta, z1, zj)
        if T is not None:
            e = e @ T.T
        m2 = np.sum((e @ Rinv) * e, axis=1)
        lik = (1.0 - epsilon) * np.exp(-0.5 * m2) + epsilon * math.exp(-0.5 * outlier_m2)
        w = self.w * lik
        total = float(w.sum())
        m2_min = float(m2.min())
        if not math.isfinite(total) or total <= 0.0:
            return False, m2_min
        self.w = w / total
        return True, m2_min

    def resample(self, roughening_m: float, shrink: bool = False) -> None:
        """Systematic resampling followed by roughening jitter N(0, sigma_r^2 I) (§4.4 step 6).

        ``shrink``: the jitter does not widen the cloud (Liu & West 2001): X <- m + a (X - m) + sigma_r xi with
        a = sqrt(1 - sigma_r^2 / lambda) along each principal axis (lambda its variance; no jitter along an axis
        narrower than sigma_r), so the resampled cloud keeps its mean and covariance while its duplicates separate."""
        idx = systematic_resample(self.w, self.rng)
        self.X = self.X[idx]
        self.E = self.E[idx]
        self.w = np.full(self.n, 1.0 / self.n)
        if roughening_m <= 0.0:
            return
        if not shrink:
            self.X += self.rng.normal(0.0, roughening_m, self.X.shape)
            return
        m, C = self.estimate()
        lam, V = np.linalg.eigh(C)
        r2 = np.minimum(roughening_m**2, 0.5 * np.maximum(lam, 0.0))  # jitter at most half of each axis' variance
        a = np.sqrt(np.where(lam > 0.0, 1.0 - r2 / np.where(lam > 0.0, lam, 1.0), 1.0))
        Y = (self.X - m) @ V
        Y = Y * a[None, :] + self.rng.standard_normal(Y.shape) * np.sqrt(r2)[None, :]
        self.X = m[None, :] + Y @ V.T

    def finite(self) -> bool:
        return bool(
            np.isfinite(self.X).all()
            and np.isfinite(self.w).all()
            and np.isfinite(self.E).all()
            and np.isfinite(self.PE).all()
        )

    def joint_estimate(self) -> tuple[F64, F64]:
        """Weighted mean (5,) and covariance (5, 5) of (x, y, DR error states)."""
        Z = np.hstack([self.X, self.E])
        m = self.w @ Z
        D = Z - m[None, :]
        C = (D.T * self.w) @ D
        C[2:, 2:] += self.PE
        return m, symmetrize(C)

    def error_estimate(self) -> tuple[F64, F64]:
        """Weighted mean and covariance of the DR error states."""
        m = self.w @ self.E
        D = self.E - m[None, :]
        C = (D.T * self.w) @ D + self.PE
        return m, symmetrize(C)
