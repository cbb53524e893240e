"""Interacting multiple model (IMM) filter over Cartesian CV models of different process noise [E].

Not in the paper (digest 003 uses one CV model, §1.6); added for manoeuvring targets (issue 15). The
paper's measurement step is kept: every model is updated with the same UT-converted plot
(y_a, R_a) and H = [I_3 0] (digest §2.6), so each model-matched filter is the linear KF of
:func:`shared.filters.kalman.update`, and the association still runs in bistatic coordinates on the
moment-matched prediction (inverse UT of its mean and covariance, digest §2.6 step 2).

Notation (Blom & Bar-Shalom 1988; Bar-Shalom, Li & Kirubarajan 2001, §11.6.6): r models j = 1..r,
model probabilities mu_j, Markov switching p_ij = P(model j at k | model i at k-1).

Switching in continuous time. Scans need not be evenly spaced (gaps, L > 2), so the switching matrix
is built from the time since the last scan tau and the models' mean sojourn times s_j:

    p_jj = exp(-tau / s_j),   p_ij = (1 - p_ii) / (r - 1)  for j != i.

One IMM cycle, for each track:

1. mixing:      c_j = sum_i p_ij mu_i,   mu_{i|j} = p_ij mu_i / c_j,
                x0_j = sum_i mu_{i|j} x_i,   P0_j = sum_i mu_{i|j} [P_i + (x_i - x0_j)(x_i - x0_j)^T];
2. prediction:  x_j^- = F x0_j,   P_j^- = F P0_j F^T + Q(tau, q_j)   (CV, digest §1.6, q_j per model);
3. the combined prediction (for gating, output when coasting):
                x^- = sum_j c_j x_j^-,   P^- = sum_j c_j [P_j^- + (x_j^- - x^-)(x_j^- - x^-)^T];
4. update with (y_a, R_a): each model's KF update; likelihood
                Lambda_j = N(nu_j; 0, S_j),  nu_j = y_a - H x_j^-,  S_j = H P_j^- H^T + R_a;
                mu_j = Lambda_j c_j / sum_l Lambda_l c_l;
5. output:      x = sum_j mu_j x_j,   P = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T].

A miss keeps x_j = x_j^-, P_j = P_j^- and mu_j = c_j. With identical models the IMM is exactly the single
filter (tested), and the mixing never loses probability mass (sum mu = 1, tested).

All functions are batched over tracks (leading dimension B) and pure.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.filters import kalman
from shared.filters.angles import wrap_pi
from shared.filters.covariance import symmetrize

from .filter import innovation, predict
from .geometry import AZ_INDEX, FloatArray
from .models import H_POS

#: smallest model probability kept after an update (keeps every model alive; renormalised)
MU_FLOOR = 1e-12


@dataclass(frozen=True)
class ImmModels:
    """The model set: CV process-noise intensities q_j (m^2/s^4) and mean sojourn times s_j (s)."""

    q_m2s4: tuple[float, ...]
    sojourn_s: tuple[float, ...]
    mu0: tuple[float, ...]

    def __post_init__(self) -> None:
        r = len(self.q_m2s4)
        if r < 1 or len(self.sojourn_s) != r or len(self.mu0) != r:
            raise ValueError("q, sojourn times and initial probabilities need one value per model")
        if abs(sum(self.mu0) - 1.0) > 1e-9 or min(self.mu0) < 0.0:
            raise ValueError("initial model probabilities must be >= 0 and sum to 1")

    @property
    def r(self) -> int:
        return len(self.q_m2s4)


def switching_matrix(tau_s: FloatArray, sojourn_s: tuple[float, ...]) -> FloatArray:
    """Pi (B, r, r) with p_jj = exp(-tau/s_j) and the rest of each row split evenly (module doc)."""
    tau = np.atleast_1d(np.asarray(tau_s, dtype=np.float64))
    s = np.asarray(sojourn_s, dtype=np.float64)
    r = s.size
    stay = np.exp(-np.maximum(tau, 0.0)[:, None] / s[None, :])  # (B, r)
    if r == 1:
        return np.ones((tau.size, 1, 1))
    Pi = np.broadcast_to(((1.0 - stay) / (r - 1))[:, :, None], (tau.size, r, r)).copy()
    idx = np.arange(r)
    Pi[:, idx, idx] = stay
    return Pi


def combine(w: FloatArray, xm: FloatArray, Pm: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Moment-matched Gaussian of a mixture: weights w (B, r), means xm (B, r, n), covariances Pm (B, r, n, n)."""
    x = np.einsum("bj,bji->bi", w, xm)
    d = xm - x[:, None, :]
    P = np.einsum("bj,bjkl->bkl", w, Pm + d[..., :, None] * d[..., None, :])
    return x, symmetrize(P)


def mix(mu: FloatArray, xm: FloatArray, Pm: FloatArray, Pi: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """IMM step 1: predicted model probabilities c (B, r) and the mixed initial conditions x0_j, P0_j."""
    joint = mu[:, :, None] * Pi  # (B, i, j): p_ij mu_i
    c = joint.sum(axis=1)  # (B, j)
    r = xm.shape[1]
    ok = c > 0.0
    w = np.where(ok[:, None, :], joint / np.where(ok, c, 1.0)[:, None, :], 1.0 / r)  # mu_{i|j}
    x0 = np.einsum("bij,bin->bjn", w, xm)
    d = xm[:, None, :, :] - x0[:, :, None, :]  # (B, j, i, n): x_i - x0_j
    spread = d[..., :, None] * d[..., None, :]  # (B, j, i, n, n)
    P0 = np.einsum("bij,bjikl->bjkl", w, Pm[:, None, :, :, :] + spread)
    return c, x0, symmetrize(P0)


def imm_predict(
    mu: FloatArray, xm: FloatArray, Pm: FloatArray, tau_s: FloatArray, models: ImmModels
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """IMM steps 1-2: (c, x_j^-, P_j^-) for each track; tau_s (B,) is the time since the last scan."""
    Pi = switching_matrix(tau_s, models.sojourn_s)
    c, x0, P0 = mix(mu, xm, Pm, Pi)
    tau = np.atleast_1d(np.asarray(tau_s, dtype=np.float64))
    xp = np.empty_like(x0)
    Pp = np.empty_like(P0)
    for j, q in enumerate(models.q_m2s4):
        xp[:, j], Pp[:, j] = predict(x0[:, j], P0[:, j], tau, q)
    return c, xp, Pp


def bistatic_loglik(z: FloatArray, z_pred: FloatArray, R_pred: FloatArray, R_plot: FloatArray) -> FloatArray:
    """ln Lambda_j from the 4-D bistatic plot: N(z - z_j^-; 0, R_b,j^- + R_plot) with the azimuth wrapped.

    z (B, 4), R_plot (B, 4, 4); per model z_pred (B, r, 4), R_pred (B, r, 4, 4) (inverse UT of x_j^-, P_j^-).
    """
    nu = innovation(z[:, None, :], z_pred)
    return kalman.log_likelihood(nu, symmetrize(R_pred + R_plot[:, None]))


def combine_measurements(c: FloatArray, zm: FloatArray, Sm: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Moment-matched predicted measurement of the mixture (B, r, 4) -> (B, 4), azimuth averaged wrap-safe."""
    ref = zm[:, :1, :]
    d = zm - ref
    d[..., AZ_INDEX] = wrap_pi(d[..., AZ_INDEX])
    mean_d, S = combine(c, d, Sm)
    z = ref[:, 0] + mean_d
    z[:, AZ_INDEX] = wrap_pi(z[:, AZ_INDEX])
    return z, S


def imm_position_update(
    c: FloatArray,
    xm: FloatArray,
    Pm: FloatArray,
    y: FloatArray,
    R: FloatArray,
    loglik: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """IMM step 4 with the converted plot y (B, 3), R (B, 3, 3): updated (mu, x_j, P_j).

    ``loglik`` (B, r): the models' log-likelihoods ln Lambda_j if computed elsewhere (the core uses the 4-D
    bistatic plot, :func:`bistatic_loglik`); by default those of the converted-position innovation.
    """
    B, r, n = xm.shape
    yr = np.repeat(y, r, axis=0)
    Rr = np.repeat(R, r, axis=0)
    x_new, P_new, nu, S = kalman.update(xm.reshape(B * r, n), Pm.reshape(B * r, n, n), yr, H_POS, Rr)
    if loglik is None:
        loglik = kalman.log_likelihood(nu, S).reshape(B, r)
    mu = update_probabilities(c, loglik)
    return mu, x_new.reshape(B, r, n), P_new.reshape(B, r, n, n)


def update_probabilities(c: FloatArray, loglik: FloatArray) -> FloatArray:
    """mu_j = Lambda_j c_j / sum_l Lambda_l c_l, in logs (far-off plots underflow), floored at MU_FLOOR."""
    logw = loglik + np.log(np.maximum(c, MU_FLOOR))
    logw = logw - logw.max(axis=1, keepdims=True)
    mu = np.exp(logw)
    mu = np.maximum(mu / mu.sum(axis=1, keepdims=True), MU_FLOOR)
    return np.asarray(mu / mu.sum(axis=1, keepdims=True), dtype=np.float64)
