"""How dead reckoning drifts: the DR error model shared by the particle filter and the EKF shadow (digest §4.3).

The paper's DR integrates the measured speed and heading, Eq. (4): X_dr = integral of V~ e(phi~) dt with
e(phi) = (cos phi, sin phi). Its errors are random processes [P]; the digest's reference model (§5.4) makes them
first-order Gauss-Markov (sigma, tau) plus white noise. Written as the measurement errors they are:

    V~   = (1 + k) V + b + w_V          k: speed scale-factor error (DVL beam geometry, transducer sound speed)
                                        b: speed bias (m/s) — the digest's additive speed error
    phi~ = phi + dphi + w_phi           dphi: heading error (rad)

To first order the DR displacement over [t_a, t_b] is then the true one plus

    DR - true = b U + dphi J dX + k dX + white,     U = integral of e(phi~) dt,   J = [[0, -1], [1, 0]]

so the three error states e = (b, dphi, k) map to position through G = [U, J dX, dX] (2 x 3):

* a speed bias is **time-driven**: it moves DR by b per second along the heading, moving or hovering (U grows
  with time even at V = 0 — the digest's additive speed error does this);
* heading and scale errors are **distance-driven**: they act through the displacement dX and vanish at rest.

Each state is Gauss-Markov over a step dt: e_b = a e_a + w, a = exp(-dt/tau), var(w) = sigma^2 (1 - a^2). The
displacement uses the trapezoid of the states over the step, (e_a + e_b)/2 (exact to O(dt/tau)^2). The white
parts add, per step, var sigma_wV^2 T_s dt along the heading and (sigma_wphi V)^2 T_s dt across it (1/T_s Hz
samples integrated by the trapezoid), plus an isotropic model floor q_floor^2 L / L_floor over a path L (turns and
speed changes between samples, the trapezoid's approximation: they happen only while moving). Nothing here depends on
distance except through dX, nothing on time except through U and the Gauss-Markov decay: the uncertainty follows the
geometry of the fixes continuously (what a cycle observes of e through the positions it fixes, the filter learns).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.filters import gauss_markov
from shared.filters.covariance import symmetrize

from .geometry import F64

#: the error states, in order
STATES = ("speed_bias_mps", "heading_rad", "speed_scale")
J90: F64 = np.array([[0.0, -1.0], [1.0, 0.0]])


@dataclass(frozen=True)
class DriftStep:
    """One prediction step of the DR error model."""

    G: F64  # (2, 3) position error per unit of each state
    a: F64  # (3,) Gauss-Markov decay of each state over the step
    w_sd: F64  # (3,) standard deviation of each state's driving noise over the step
    Q_white: F64  # (2, 2) white displacement noise, m^2


@dataclass(frozen=True)
class DriftModel:
    """Parameters of the DR error model (sigmas of the stationary processes, correlation times)."""

    bias_mps: float
    bias_tau_s: float
    heading_rad: float
    heading_tau_s: float
    scale: float
    scale_tau_s: float
    speed_white_mps: float
    heading_white_rad: float
    sample_period_s: float
    floor_m: float
    floor_path_m: float

    @property
    def sigma(self) -> F64:
        """Stationary standard deviations of (b, dphi, k)."""
        return np.array([self.bias_mps, self.heading_rad, self.scale])

    @property
    def tau(self) -> F64:
        return np.array([self.bias_tau_s, self.heading_tau_s, self.scale_tau_s])

    def prior_cov(self) -> F64:
        """Stationary covariance of the error states (3 x 3, diagonal)."""
        return np.diag(self.sigma**2)

    def step(self, dt_s: float, dX: F64, U: F64) -> DriftStep:
        """The model over one step of dt_s with DR displacement dX (m) and heading integral U (s)."""
        a, w_sd = gauss_markov.discretise_sd(dt_s, self.tau, self.sigma)
        G = np.column_stack([U, J90 @ dX, dX])
        return DriftStep(G=G, a=a, w_sd=w_sd, Q_white=self.white_cov(dt_s, dX, U))

    def white_cov(self, dt_s: float, dX: F64, U: F64) -> F64:
        """White DR displacement noise over a step: along-heading speed noise, cross-heading heading noise, floor."""
        if dt_s <= 0.0:
            return np.zeros((2, 2))
        Ts = self.sample_period_s
        nu = math.hypot(float(U[0]), float(U[1]))
        along = U / nu if nu > 1e-12 else np.array([1.0, 0.0])
        cross = J90 @ along
        L2 = float(dX @ dX)
        var_along = self.speed_white_mps**2 * Ts * dt_s
        var_cross = self.heading_white_rad**2 * Ts * L2 / dt_s
        floor = self.floor_m**2 * math.sqrt(L2) / self.floor_path_m
        Q = var_along * np.outer(along, along) + var_cross * np.outer(cross, cross) + floor * np.eye(2)
        return symmetrize(Q)

    def position_cov_of_states(self, G: F64) -> F64:
        """Displacement covariance G P0 G^T the stationary error states alone would cause over a step (m^2)."""
        return G @ self.prior_cov() @ G.T


def gm_path_var(dt: float, tau: float) -> float:
    """Variance of the path integral of a unit-variance Gauss-Markov process over dt (correlation time tau), s^2:
    2 tau^2 (dt/tau - 1 + exp(-dt/tau)); about dt^2 for dt << tau, 2 tau dt for dt >> tau."""
    x = dt / tau
    if x < 1e-4:
        return dt * dt
    return 2.0 * tau * tau * (x - 1.0 + math.exp(-x))
