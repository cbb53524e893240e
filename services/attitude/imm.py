"""Interacting multiple models (IMM) over the 9-state of eq. (3): the manoeuvre-robust filter of the default preset.

The paper's filter (eq. 3) has one random-jerk level D: small D lags in turns, large D is noisy on straight
legs (digest §4.5, §5.7). The IMM (Blom & Bar-Shalom 1988; Bar-Shalom, Li & Kirubarajan 2001, §11.6) runs one
Kalman filter per motion model j = 1..M (:class:`~.config.MotionModel`: the paper's CA model at several jerk
levels, or a Singer model of mean-reverting acceleration) on the same state alpha, and a Markov chain over the
models with transition probabilities pi_ij over a step dt (p_ii = exp(-dt / sojourn_i), the rest shared equally).
One cycle, for a plot z with covariance R_z at dt after the last:

1. mixing:      c_j = sum_i pi_ij mu_i,   mu_i|j = pi_ij mu_i / c_j,
                alpha0_j = sum_i mu_i|j alpha_i,
                P0_j = sum_i mu_i|j [P_i + (alpha_i - alpha0_j)(alpha_i - alpha0_j)^T];
2. per model:   alpha~_j = F_j alpha0_j,  P~_j = F_j P0_j F_j^T + Q_j           (eq. 3 with the model's F, Q)
                nu_j = z - H alpha~_j,    S_j = H P~_j H^T + R_z,                Lambda_j = N(nu_j; 0, S_j)
                alpha_j, P_j: the Kalman update of eq. (3) (Joseph form, filter.update);
3. probability: mu_j = Lambda_j c_j / sum_k Lambda_k c_k;
4. output:      alpha = sum_j mu_j alpha_j,  P = sum_j mu_j [P_j + (alpha_j - alpha)(alpha_j - alpha)^T].

The angles (eqs. 4-5) and their sigmas are computed from the output (alpha, P), the first two moments of the
Gaussian mixture, so a sigma covers the spread between the models as well as each model's own uncertainty.
With one model (or M equal models) the cycle is exactly the Kalman filter of eq. (3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .config import MotionModel
from .filter import update
from .geometry import F64
from .models import POS, block_diagonal, process_noise, singer_axis, transition

_LOG_2PI = math.log(2.0 * math.pi)


@lru_cache(maxsize=1024)
def model_matrices(model: MotionModel, dt_s: float) -> tuple[F64, F64]:
    """(F, Q) (9x9, read-only) of one motion model over dt_s: CA (B, M = S^T D S) or Singer (Van Loan)."""
    if model.kind == "ca":
        assert model.sigma_jerk_mps3 is not None
        d = model.sigma_jerk_mps3**2
        f, q = transition(dt_s), process_noise(dt_s, (d, d, d))
    else:
        assert model.sigma_accel_mps2 is not None and model.tau_s is not None
        fa, qa = singer_axis(abs(dt_s), model.sigma_accel_mps2, model.tau_s)
        if dt_s < 0.0:  # backwards in time (never used by the core: plots older than the state are dropped)
            fa = np.asarray(np.linalg.inv(fa), dtype=np.float64)
        f, q = block_diagonal(fa), block_diagonal(qa)
    f.setflags(write=False)
    q.setflags(write=False)
    return f, q


@lru_cache(maxsize=256)
def transition_probabilities(models: tuple[MotionModel, ...], dt_s: float) -> F64:
    """pi (M x M), pi[i, j] = P(model j at t + dt | model i at t): p_ii = exp(-|dt| / sojourn_i), the rest of
    row i shared equally among the other models. Rows sum to 1."""
    m = len(models)
    if m == 1:
        pi = np.ones((1, 1))
    else:
        stay = np.array([math.exp(-abs(dt_s) / mod.sojourn_s) for mod in models])
        pi = np.repeat(((1.0 - stay) / (m - 1))[:, None], m, axis=1)
        np.fill_diagonal(pi, stay)
    pi.setflags(write=False)
    return pi


@dataclass
class ImmState:
    """Per-model estimates alpha_j (M, 9), covariances P_j (M, 9, 9) and model probabilities mu (M,)."""

    xs: F64
    ps: F64
    mu: F64

    @classmethod
    def start(cls, x: F64, p: F64, mu0: tuple[float, ...]) -> ImmState:
        """Every model starts from the same estimate (the FSF start, eq. 2) with probabilities mu0."""
        m = len(mu0)
        return cls(np.repeat(x[None], m, axis=0), np.repeat(p[None], m, axis=0), np.asarray(mu0, dtype=np.float64))

    def copy(self) -> ImmState:
        return ImmState(self.xs.copy(), self.ps.copy(), self.mu.copy())


def combine(xs: F64, ps: F64, mu: F64) -> tuple[F64, F64]:
    """Moments of the mixture: alpha = sum mu_j alpha_j, P = sum mu_j [P_j + d_j d_j^T], d_j = alpha_j - alpha."""
    x = mu @ xs
    d = xs - x
    p = np.einsum("j,jkl->kl", mu, ps) + (d.T * mu) @ d
    return x, 0.5 * (p + p.T)


def mix(state: ImmState, pi: F64) -> tuple[F64, F64, F64]:
    """Step 1: (c (M,), alpha0 (M, 9), P0 (M, 9, 9)): the predicted model probabilities and mixed initial
    conditions of every model."""
    c = state.mu @ pi
    w = (state.mu[:, None] * pi) / c[None, :]  # w[i, j] = mu_i|j, columns sum to 1
    x0 = w.T @ state.xs
    p0 = np.empty_like(state.ps)
    for j in range(len(c)):
        d = state.xs - x0[j]
        p0[j] = np.einsum("i,ikl->kl", w[:, j], state.ps) + (d.T * w[:, j]) @ d
    return c, x0, p0


def predict(state: ImmState, models: tuple[MotionModel, ...], dt_s: float) -> tuple[F64, F64, F64]:
    """Steps 1-2 without a plot: (c, alpha~ (M, 9), P~ (M, 9, 9)), each model predicted from its mixed start."""
    c, x0, p0 = mix(state, transition_probabilities(models, float(dt_s)))
    xp = np.empty_like(x0)
    pp = np.empty_like(p0)
    for j, model in enumerate(models):
        f, q = model_matrices(model, float(dt_s))
        xp[j] = f @ x0[j]
        pp[j] = f @ p0[j] @ f.T + q
    return c, xp, pp


def predict_combined(state: ImmState, models: tuple[MotionModel, ...], dt_s: float) -> tuple[F64, F64]:
    """The mixture's predicted moments at t + dt (on-demand extrapolation, coasting)."""
    c, xp, pp = predict(state, models, dt_s)
    return combine(xp, pp, c)


@dataclass(frozen=True)
class ImmUpdate:
    """The result of one IMM cycle with a plot."""

    state: ImmState
    x: F64  # output alpha (mixture mean)
    p: F64  # output P (mixture covariance)
    nis: float  # nu^T S^-1 nu of the plot against the mixture's predicted moments
    nis_models: F64  # per-model NIS (M,)
    log_likelihood: F64  # log Lambda_j (M,)


def update_models(c: F64, xp: F64, pp: F64, z: F64, rz: F64) -> ImmUpdate:
    """Steps 2 (update) to 4 from the predicted probabilities c and per-model predictions (``predict``), with the
    plot z (m, frame E) of covariance R_z. Raises numpy.linalg.LinAlgError if an innovation covariance is not
    positive definite."""
    m = len(c)
    xs = np.empty_like(xp)
    ps = np.empty_like(pp)
    nis_j = np.empty(m)
    loglik = np.empty(m)
    for j in range(m):
        xs[j], ps[j], nis_j[j] = update(xp[j], pp[j], z, rz)
        loglik[j] = -0.5 * (nis_j[j] + math.log(_det3((pp[j][POS, POS] + rz).tolist())) + 3.0 * _LOG_2PI)
    lw = loglik + np.log(np.maximum(c, 1e-300))
    lw -= lw.max()
    mu = np.exp(lw)
    mu /= mu.sum()
    x, p = combine(xs, ps, mu)
    x_bar, p_bar = combine(xp, pp, c)
    nu = z - x_bar[POS]
    nis = float(nu @ np.linalg.solve(p_bar[POS, POS] + rz, nu))
    return ImmUpdate(ImmState(xs, ps, mu), x, p, nis, nis_j, loglik)


def _det3(s: list[list[float]]) -> float:
    """Determinant of a 3x3 matrix (rule of Sarrus); S is positive definite here (the update's Cholesky passed)."""
    (a, b, c), (d, e, f), (g, h, i) = s
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def step(state: ImmState, models: tuple[MotionModel, ...], dt_s: float, z: F64, rz: F64) -> ImmUpdate:
    """One IMM cycle (steps 1-4) with plot z of covariance R_z (``predict`` then ``update_models``)."""
    return update_models(*predict(state, models, dt_s), z, rz)


def gate_nis(xp: F64, pp: F64, z: F64, rz: F64, widen_m: float) -> float:
    """The manoeuvre gate's statistic from the per-model predictions: min over models of
    nu_j^T (S_j + w^2 I)^-1 nu_j, w = ``widen_m`` = a dt^2 / 2 for an unmodelled acceleration change a over the
    step, i.e. the plot against the most permissive model widened by that manoeuvre."""
    widen = widen_m * widen_m * np.eye(3)
    best = math.inf
    for j in range(xp.shape[0]):
        nu = z - xp[j][POS]
        best = min(best, float(nu @ np.linalg.solve(pp[j][POS, POS] + rz + widen, nu)))
    return best
