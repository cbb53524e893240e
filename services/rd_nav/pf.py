"""The paper's particle filter (digest §4.4, Fig. 4), vectorised over particles with numpy.

State: N particles X_n = (x_n, y_n) (north, east, m) with weights p_n. Steps: initialise in a disc,
predict with the DR displacement plus diffusion (Eq. 5), robust Gaussian weight update on the range
differences, normalise, systematic resampling + roughening when N_eff < f*N, estimate by Eq. (6)-(7).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

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
        self.w: F64 = np.full(n, 1.0 / n)

    # ----- initialisation ---------------------------------------------------------------------
    def init_disc(self, center: F64, radius_m: float) -> None:
        """Uniform in a disc of radius R0 around the start point, p_n = 1/N (§4.4 step 1)."""
        r = radius_m * np.sqrt(self.rng.random(self.n))
        a = self.rng.random(self.n) * (2.0 * math.pi)
        self.X = np.column_stack([center[0] + r * np.cos(a), center[1] + r * np.sin(a)])
        self.w = np.full(self.n, 1.0 / self.n)

    def init_gaussian(self, mean: F64, cov: F64) -> None:
        """Re-seed as N(mean, cov) (§4.4 step 8)."""
        L = np.linalg.cholesky(0.5 * (cov + cov.T))
        self.X = mean[None, :] + self.rng.standard_normal((self.n, 2)) @ L.T
        self.w = np.full(self.n, 1.0 / self.n)

    # ----- prediction -------------------------------------------------------------------------
    def predict(self, dX: F64, q_sigma_m: float) -> None:
        """Eq. (5) for every particle plus diffusion N(0, q^2 I)."""
        self.X += dX[None, :]
        if q_sigma_m > 0.0:
            self.X += self.rng.normal(0.0, q_sigma_m, self.X.shape)

    # ----- estimate ---------------------------------------------------------------------------
    def estimate(self) -> tuple[F64, F64]:
        """Weighted mean (Eq. 6) and cloud covariance Q_k (Eq. 7), symmetrised."""
        m = self.w @ self.X
        D = self.X - m[None, :]
        Q = (D.T * self.w) @ D
        return m, 0.5 * (Q + Q.T)

    def map_estimate(self, threshold: float) -> F64 | None:
        """The maximum-weight particle if its weight exceeds the threshold (§4.4 step 7)."""
        k = int(np.argmax(self.w))
        return self.X[k].copy() if self.w[k] > threshold else None

    def n_eff(self) -> float:
        return float(1.0 / np.sum(self.w * self.w))

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
    ) -> tuple[bool, float]:
        """p_n <- p_n [(1-eps) exp(-e^T R^-1 e / 2) + eps exp(-outlier/2)], normalised (§4.4 steps 3-5).

        With ``T`` the residuals are transformed first (e <- T e) and ``Rinv`` is (T R T^T)^-1.
        Returns (ok, smallest m^2 over the particles); ok is False (weights kept) if the sum is not finite/zero.
        """
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

    def resample(self, roughening_m: float) -> None:
        """Systematic resampling followed by roughening jitter N(0, sigma_r^2 I) (§4.4 step 6)."""
        cs = np.cumsum(self.w)
        cs[-1] = 1.0
        u = (self.rng.random() + np.arange(self.n)) / self.n
        idx = np.minimum(np.searchsorted(cs, u, side="right"), self.n - 1)
        self.X = self.X[idx]
        if roughening_m > 0.0:
            self.X += self.rng.normal(0.0, roughening_m, self.X.shape)
        self.w = np.full(self.n, 1.0 / self.n)

    def finite(self) -> bool:
        return bool(np.isfinite(self.X).all() and np.isfinite(self.w).all())
