"""EKF baseline in shadow of the particle filter (digest §4.5): same DR prediction, q, R and gate.

State x = (x, y) (north, east, m). Predict x <- x + dX, P <- P + q^2 I. Update with the range-difference
vector d and rows H_j = (u_j - u_1)_xy, Joseph form, symmetrised covariance, NIS gate chi2_{M}.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import F64, jacobian_d, predict_d


@dataclass(frozen=True)
class EkfUpdate:
    accepted: bool
    nis: float
    residual_m: F64


class EkfShadow:
    """A two-state EKF on the PF's inputs."""

    def __init__(self) -> None:
        self.x: F64 = np.zeros(2)
        self.P: F64 = np.eye(2)
        self.initialised = False
        self.rejections = 0

    def init(self, mean: F64, cov: F64) -> None:
        self.x = np.array(mean, dtype=np.float64)
        self.P = 0.5 * (cov + cov.T)
        self.initialised = True
        self.rejections = 0

    def predict(self, dX: F64, q_var_m2: float) -> None:
        self.x = self.x + dX
        self.P = self.P + q_var_m2 * np.eye(2)

    def update(
        self,
        d: F64,
        R: F64,
        leader: F64,
        followers: F64,
        delta: F64,
        z1: float,
        zj: F64,
        gate: float | None,
    ) -> EkfUpdate:
        xr = self.x.reshape(1, 2)
        e = d - predict_d(xr, leader, followers, delta, z1, zj)[0]
        H = jacobian_d(xr, leader, followers, delta, z1, zj)[0]
        S = H @ self.P @ H.T + R
        S = 0.5 * (S + S.T)
        Sinv_e = np.linalg.solve(S, e)
        nis = float(e @ Sinv_e)
        if gate is not None and not nis <= gate:
            self.rejections += 1
            return EkfUpdate(False, nis, e)
        K = np.linalg.solve(S, H @ self.P).T  # P H^T S^-1 (S and P symmetric)
        A = np.eye(2) - K @ H
        P = A @ self.P @ A.T + K @ R @ K.T  # Joseph form
        self.x = self.x + K @ e
        self.P = 0.5 * (P + P.T)
        self.rejections = 0
        return EkfUpdate(True, nis, e)
