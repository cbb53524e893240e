"""EKF baseline in shadow of the particle filter (digest §4.5): same DR prediction, process model, R and gate.

State z = (x, y, b, dphi, k): the horizontal position (north, east, m) and the DR error states of
:mod:`services.rd_nav.drift` (speed bias m/s, heading error rad, speed scale error). With the digest's white
process noise the error states keep zero covariance and the filter is the digest's two-state EKF.

Predict (linear, exact for the drift model's discretisation)::

    x_b = x_a + dX - G (e_a + e_b)/2 ,   e_b = A e_a + w          (A = diag(a), w ~ N(0, diag(w_sd^2)))
    F = [[I, -G (I + A)/2], [0, A]],     Q = [[G W G^T / 4 + Q_white, -G W / 2], [-W G^T / 2, W]],  W = diag(w_sd^2)

or, digest: x <- x + dX, P <- P + q^2 I on the position block. Update with the range-difference vector d and
rows H_j = (u_j - u_1)_xy (zeros for the error states), Joseph form, symmetrised covariance, NIS gate chi2_M.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.filters import kalman
from shared.filters.covariance import symmetrize

from .drift import DriftStep
from .geometry import F64, error_jacobian, follower_units, jacobian_d, predict_d

N_STATE = 5


@dataclass(frozen=True)
class EkfUpdate:
    accepted: bool
    nis: float
    residual_m: F64


class EkfShadow:
    """An EKF on the PF's inputs: position plus DR error states."""

    def __init__(self) -> None:
        self.z: F64 = np.zeros(N_STATE)
        self.Pz: F64 = np.eye(N_STATE)
        self.initialised = False
        self.rejections = 0

    @property
    def x(self) -> F64:
        """Horizontal position estimate (north, east), m."""
        return self.z[:2]

    @x.setter
    def x(self, value: F64) -> None:
        self.z = self.z.copy()
        self.z[:2] = value

    @property
    def P(self) -> F64:
        """Its 2 x 2 covariance, m^2."""
        return self.Pz[:2, :2]

    @P.setter
    def P(self, value: F64) -> None:
        self.Pz = self.Pz.copy()
        self.Pz[:2, :2] = value

    def init(self, mean: F64, cov: F64, error_cov: F64 | None = None) -> None:
        self.z = np.zeros(N_STATE)
        self.z[:2] = np.asarray(mean, dtype=np.float64)
        self.Pz = np.zeros((N_STATE, N_STATE))
        self.Pz[:2, :2] = symmetrize(cov)
        if error_cov is not None:
            self.Pz[2:, 2:] = error_cov
        self.initialised = True
        self.rejections = 0

    def predict(self, dX: F64, q_var_m2: float) -> None:
        """The digest's prediction: x <- x + dX, P <- P + q^2 I (position block)."""
        self.z[:2] = self.z[:2] + dX
        self.Pz[:2, :2] = self.Pz[:2, :2] + q_var_m2 * np.eye(2)

    def predict_drift(self, dX: F64, step: DriftStep) -> None:
        """Prediction with the DR error states (module docstring)."""
        G, A = step.G, np.diag(step.a)
        W = np.diag(step.w_sd**2)
        F = np.eye(N_STATE)
        F[:2, 2:] = -0.5 * G @ (np.eye(3) + A)
        F[2:, 2:] = A
        Q = np.zeros((N_STATE, N_STATE))
        Q[:2, :2] = 0.25 * G @ W @ G.T + step.Q_white
        Q[:2, 2:] = -0.5 * G @ W
        Q[2:, :2] = Q[:2, 2:].T
        Q[2:, 2:] = W
        b = np.zeros(N_STATE)
        b[:2] = dX
        self.z, self.Pz = kalman.predict(self.z, self.Pz, F, Q, b)

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
        G: F64 | None = None,
    ) -> EkfUpdate:
        """Update with one cycle; with ``G`` (M, 2, 3) the motion compensation is corrected by the estimated DR
        errors, delta_j - G_j e, and h depends on e through it (dh_j/de = -H_j G_j)."""
        xr = self.z[:2].reshape(1, 2)
        if G is not None:
            delta = delta - np.einsum("mij,j->mi", G, self.z[2:])
        e = d - predict_d(xr, leader, followers, delta, z1, zj)[0]
        Hx = jacobian_d(xr, leader, followers, delta, z1, zj)[0]
        H = np.zeros((Hx.shape[0], N_STATE))
        H[:, :2] = Hx
        if G is not None:
            H[:, 2:] = error_jacobian(follower_units(self.z[:2], zj, delta, followers), G)
        S = kalman.innovation_covariance(self.Pz, H, R)
        nis = float(e @ np.linalg.solve(S, e))
        if gate is not None and not nis <= gate:
            self.rejections += 1
            return EkfUpdate(False, nis, e)
        K = np.linalg.solve(S, H @ self.Pz).T  # P H^T S^-1 (S and P symmetric)
        self.z = self.z + K @ e
        self.Pz = kalman.joseph(self.Pz, K, H, R)
        self.rejections = 0
        return EkfUpdate(True, nis, e)
