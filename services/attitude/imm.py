"""Interacting multiple models (IMM) over the 9-state of eq. (3): the manoeuvre-robust filter of the default preset.

The paper's filter (eq. 3) has one random-jerk level D: small D lags in turns, large D is noisy on straight
legs (digest §4.5, §5.7). The IMM (Blom & Bar-Shalom 1988; Bar-Shalom, Li & Kirubarajan 2001, §11.6) runs one
filter per motion model j = 1..M (:class:`~.config.MotionModel`: the paper's CA model at several jerk levels, a
Singer model of mean-reverting acceleration, or a nearly coordinated turn (CT) with a turn-rate state) and a Markov
chain over the models with transition probabilities pi_ij over a step dt (p_ii = exp(-dt / sojourn_i), the rest
shared equally). One cycle, for a plot z with covariance R_z at dt after the last:

1. mixing:      c_j = sum_i pi_ij mu_i,   mu_i|j = pi_ij mu_i / c_j,
                alpha0_j = sum_i mu_i|j alpha_i,
                P0_j = sum_i mu_i|j [P_i + (alpha_i - alpha0_j)(alpha_i - alpha0_j)^T];
2. per model:   alpha~_j = F_j alpha0_j,  P~_j = F_j P0_j F_j^T + Q_j           (eq. 3 with the model's F, Q;
                                                                                the CT model: see below)
                nu_j = z - H alpha~_j,    S_j = H P~_j H^T + R_z,                Lambda_j = N(nu_j; 0, S_j)
                alpha_j, P_j: the Kalman update of eq. (3) (Joseph form, filter.update);
3. probability: mu_j = Lambda_j c_j / sum_k Lambda_k c_k;
4. output:      alpha = sum_j mu_j alpha_j,  P = sum_j mu_j [P_j + (alpha_j - alpha)(alpha_j - alpha)^T].

The angles (eqs. 4-5) and their sigmas are computed from the output (alpha, P), the first two moments of the
Gaussian mixture, so a sigma covers the spread between the models as well as each model's own uncertainty.
With one model (or M equal models) the cycle is exactly the Kalman filter of eq. (3).

**Models of different state.** The CT model (:func:`~.models.ct_step`, Bar-Shalom, Li & Kirubarajan §11.7; Li &
Jilkov 2003, "Survey of maneuvering target tracking, part I", §4) needs the turn rate omega, which the CA and
Singer models do not carry. Two ways are usual: augment every model with omega (the CV/CA models with a dummy
omega of their own, mixed like any component), or mix only the common sub-state. Here every model of a bank with a
CT model holds the 10-state [alpha, omega], but a CA/Singer model's omega is not a state of its own: after each
update (and at the start) it is set to the turn rate its own velocity and acceleration imply,
omega = (Vx az - Vz ax) / V_h^2, with first-order moments (:func:`augment`). So

* mixing INTO a CA/Singer model uses only the 9-state part: exactly the mixing of the common sub-state (its
  omega is overwritten after the update and never enters its dynamics);
* mixing INTO the CT model mixes full 10-states: the CT model's own omega (its memory of the turn) with the
  turn rates the other models' accelerations imply, weighted by mu_i|j like every other component. A dummy omega
  of a CA model would instead drift away from what its acceleration says and feed the CT model a turn rate that
  no data supports; mixing the common sub-state only would restart the CT model's omega from its own last value
  whatever the other models saw (at a roll-in, the onset model sees the turn first).

The CT model's prediction (:func:`~.models.ct_predict`) integrates the exact transition given omega over omega's
Gaussian by Gauss-Hermite quadrature (``ct_prediction: ekf``: the EKF of :func:`~.models.ct_step`, the exact
Jacobian of the discrete map, its omega column the Frechet derivative of expm). The output (alpha, P) is the
9-state part of the mixture; the turn rate stays internal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from shared.filters import kalman
from shared.filters.covariance import symmetrize

from .config import MotionModel
from .filter import update
from .geometry import F64
from .models import OMEGA, POS, block_diagonal, ct_predict, ct_step, process_noise, singer_axis, transition, turn_rate


@lru_cache(maxsize=1024)
def model_matrices(model: MotionModel, dt_s: float) -> tuple[F64, F64]:
    """(F, Q) (9x9, read-only) of one motion model over dt_s: CA (B, M = S^T D S, D = diag(sigma_j^2, (k sigma_j)^2,
    sigma_j^2) with k = ``vertical_jerk_factor``) or Singer (Van Loan)."""
    if model.kind == "ca":
        assert model.sigma_jerk_mps3 is not None
        # D_a = diag(sigma_j^2, (k sigma_j)^2, sigma_j^2) in E [north, up, east]; k = 1 multiplies exactly
        d = model.sigma_jerk_mps3**2
        d_up = (model.vertical_jerk_factor * model.sigma_jerk_mps3) ** 2
        f, q = transition(dt_s), process_noise(dt_s, (d, d_up, d))
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
    row i shared equally among the other models (those named in the model's ``exits_to``, if given). Rows sum
    to 1. (A CT model with ``exit_heading_change_deg`` has its row at omega^ = 0 here: see
    :func:`transition_matrix`.)"""
    m = len(models)
    if m == 1:
        pi = np.ones((1, 1))
    else:
        pi = np.zeros((m, m))
        for i, mod in enumerate(models):
            _fill_row(pi, models, i, math.exp(-abs(dt_s) / mod.sojourn_s))
    pi.setflags(write=False)
    return pi


def _fill_row(pi: F64, models: tuple[MotionModel, ...], i: int, stay: float) -> None:
    """Row i of pi: p_ii = ``stay``, 1 - stay shared equally among the models i exits to (``exits_to``)."""
    mod = models[i]
    targets = [j for j, o in enumerate(models) if j != i and (mod.exits_to is None or o.name in mod.exits_to)]
    pi[i] = 0.0
    pi[i, targets] = (1.0 - stay) / len(targets)
    pi[i, i] = stay


def heading_exit_stay(model: MotionModel, dt_s: float, omega_rps: float) -> float:
    """p_jj over dt of a CT model whose turn ends after a mean heading change dpsi (``exit_heading_change_deg``):
    exp(-|dt| lambda), lambda = max(|omega^| / dpsi, 1 / sojourn_s) (1/s; omega^ in rad/s, dpsi in rad)."""
    assert model.exit_heading_change_deg is not None
    omega = abs(omega_rps) if math.isfinite(omega_rps) else 0.0  # no turn-rate estimate: the longest sojourn
    rate = max(omega / math.radians(model.exit_heading_change_deg), 1.0 / model.sojourn_s)
    return math.exp(-abs(dt_s) * rate)


def transition_matrix(state: ImmState, models: tuple[MotionModel, ...], dt_s: float) -> F64:
    """pi over dt from ``state``: :func:`transition_probabilities`, with the row of every CT model that has
    ``exit_heading_change_deg`` set from its own turn-rate estimate (:func:`heading_exit_stay`); without such a
    model, :func:`transition_probabilities` itself."""
    pi = transition_probabilities(models, dt_s)
    rows = [i for i, mod in enumerate(models) if mod.exit_heading_change_deg is not None]
    if not rows or len(models) == 1:
        return pi
    pi = pi.copy()
    for i in rows:
        _fill_row(pi, models, i, heading_exit_stay(models[i], dt_s, float(state.xs[i, OMEGA])))
    return pi


def state_dim(models: tuple[MotionModel, ...]) -> int:
    """9 (the state of eq. 3), or 10 when the bank has a coordinated-turn model (the turn rate appended)."""
    return 10 if any(m.kind == "ct" for m in models) else 9


#: turn rates implied by a CA/Singer state are capped at this standard deviation (rad/s, 17 deg/s: beyond any
#: aircraft's sustained turn) before a CT model mixes them in: right after the FSF start the acceleration is
#: known to tens of m/s^2, and a turn-rate spread of rad/s would spread the CT model's prediction over circles
OMEGA_SIGMA_CAP = 0.3
#: the variance (rad^2/s^2) added to an implied turn rate: it is a function of the state, so its covariance with
#: the state would otherwise be singular
OMEGA_NUGGET = 1e-8


def augment(x: F64, p: F64) -> None:
    """In place: set the turn rate (index 9) of a 10-state to the one its velocity and acceleration imply,
    omega = (Vx az - Vz ax) / V_h^2, with first-order moments: cov(omega, alpha) = g^T P, var = g^T P g + nugget
    (g = d(omega)/d(alpha)). This is the CA and Singer models' view of the turn rate, which they do not carry:
    a CT model mixes it in like any other component. A variance above OMEGA_SIGMA_CAP^2 is scaled down to it
    with its covariances (a congruence D P D, D = diag(1, .., 1, s), so P stays positive semi-definite); the mean
    is clipped to +-1 rad/s (a state of a diverging start, not an aircraft)."""
    w, _, p9g, var, s = implied_turn_rate(x, p)
    x[OMEGA] = max(-1.0, min(1.0, w))
    p[OMEGA, :9] = s * p9g
    p[:9, OMEGA] = s * p9g
    p[OMEGA, OMEGA] = s * s * var + OMEGA_NUGGET


def implied_turn_rate(x: F64, p: F64) -> tuple[float, F64, F64, float, float]:
    """What :func:`augment` sets: (omega, g = d(omega)/d(alpha) (9,), P9 g, g^T P9 g, the cap's scale s); the
    covariance of the implied omega with any variable y is s g^T cov(alpha9, y)."""
    w, g = turn_rate(x)
    p9g = p[:9, :9] @ g
    var = float(g @ p9g)
    s = 1.0 if var <= OMEGA_SIGMA_CAP * OMEGA_SIGMA_CAP else OMEGA_SIGMA_CAP / math.sqrt(var)
    return w, g, p9g, var, s


def _augment_models(xs: F64, ps: F64, models: tuple[MotionModel, ...]) -> None:
    """:func:`augment` every CA/Singer model of a 10-state bank (in place)."""
    if xs.shape[1] == 10:
        for j, model in enumerate(models):
            if model.kind != "ct":
                augment(xs[j], ps[j])


@dataclass
class ImmState:
    """Per-model estimates alpha_j (M, n), covariances P_j (M, n, n) and model probabilities mu (M,); n = 9, or
    10 with a CT model in the bank (:func:`state_dim`; the CA/Singer models' omega is the implied one)."""

    xs: F64
    ps: F64
    mu: F64

    @classmethod
    def start(cls, x: F64, p: F64, mu0: tuple[float, ...], models: tuple[MotionModel, ...] | None = None) -> ImmState:
        """Every model starts from the same estimate (the FSF start, eq. 2) with probabilities mu0; with a CT model
        in ``models`` the state gets the implied turn rate (:func:`augment`)."""
        m = len(mu0)
        n = 9 if models is None else state_dim(models)
        x0 = np.zeros(n)
        p0 = np.zeros((n, n))
        x0[:9] = x[:9]
        p0[:9, :9] = p[:9, :9]
        if n == 10:
            augment(x0, p0)
        return cls(np.repeat(x0[None], m, axis=0), np.repeat(p0[None], m, axis=0), np.asarray(mu0, dtype=np.float64))

    def copy(self) -> ImmState:
        return ImmState(self.xs.copy(), self.ps.copy(), self.mu.copy())


def combine(xs: F64, ps: F64, mu: F64) -> tuple[F64, F64]:
    """Moments of the mixture: alpha = sum mu_j alpha_j, P = sum mu_j [P_j + d_j d_j^T], d_j = alpha_j - alpha."""
    x = mu @ xs
    d = xs - x
    p = np.einsum("j,jkl->kl", mu, ps) + (d.T * mu) @ d
    return x, symmetrize(p)


def mixing_weights(mu: F64, pi: F64) -> tuple[F64, F64]:
    """(c (M,), w (M, M)): the predicted model probabilities c_j = sum_i pi_ij mu_i and the mixing weights
    w[i, j] = mu_i|j = pi_ij mu_i / c_j (columns sum to 1)."""
    c = mu @ pi
    return c, (mu[:, None] * pi) / c[None, :]


def mix(state: ImmState, pi: F64) -> tuple[F64, F64, F64]:
    """Step 1: (c (M,), alpha0 (M, 9), P0 (M, 9, 9)): the predicted model probabilities and mixed initial
    conditions of every model."""
    c, w = mixing_weights(state.mu, pi)
    x0 = w.T @ state.xs
    p0 = np.empty_like(state.ps)
    for j in range(len(c)):
        d = state.xs - x0[j]
        p0[j] = np.einsum("i,ikl->kl", w[:, j], state.ps) + (d.T * w[:, j]) @ d
    return c, x0, p0


def predict(state: ImmState, models: tuple[MotionModel, ...], dt_s: float) -> tuple[F64, F64, F64]:
    """Steps 1-2 without a plot: (c, alpha~ (M, 9), P~ (M, 9, 9)), each model predicted from its mixed start."""
    c, x0, p0 = mix(state, transition_matrix(state, models, float(dt_s)))
    xp = np.empty_like(x0)
    pp = np.empty_like(p0)
    for j, model in enumerate(models):
        if model.kind == "ct":  # quadrature over omega (or the EKF's linearisation): models.ct_predict / ct_step
            assert model.sigma_accel_mps2 is not None and model.tau_s is not None
            if model.ct_prediction == "quadrature":
                xp[j], pp[j] = ct_predict(x0[j], p0[j], float(dt_s), model.sigma_accel_mps2, model.tau_s, model.q_omega)
            else:
                xp[j], f, q = ct_step(x0[j], float(dt_s), model.sigma_accel_mps2, model.tau_s, model.q_omega)
                pp[j] = kalman.predict_covariance(p0[j], f, q, symmetrise=False)
            continue
        f, q = model_matrices(model, float(dt_s))
        if x0.shape[1] == 9:
            xp[j], pp[j] = kalman.predict(x0[j], p0[j], f, q, symmetrise=False)
        else:  # the implied turn rate is carried along unchanged and re-derived after the update
            xp[j, :9] = f @ x0[j, :9]
            xp[j, 9] = x0[j, 9]
            fp = f @ p0[j, :9, :]
            pp[j, :9, :9] = fp[:, :9] @ f.T + q
            pp[j, :9, 9] = fp[:, 9]
            pp[j, 9, :9] = fp[:, 9]
            pp[j, 9, 9] = p0[j, 9, 9]
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


def update_models(
    c: F64, xp: F64, pp: F64, z: F64, rz: F64, models: tuple[MotionModel, ...] | None = None
) -> ImmUpdate:
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
        loglik[j] = kalman.log_likelihood_3(nis_j[j], pp[j][POS, POS] + rz)
    if models is not None:
        _augment_models(xs, ps, models)
    lw = loglik + np.log(np.maximum(c, 1e-300))
    lw -= lw.max()
    mu = np.exp(lw)
    mu /= mu.sum()
    x, p = combine(xs, ps, mu)
    x_bar, p_bar = combine(xp, pp, c)
    nu = z - x_bar[POS]
    nis = kalman.nis_solve(nu, p_bar[POS, POS] + rz)
    return ImmUpdate(ImmState(xs, ps, mu), x, p, nis, nis_j, loglik)


def step(state: ImmState, models: tuple[MotionModel, ...], dt_s: float, z: F64, rz: F64) -> ImmUpdate:
    """One IMM cycle (steps 1-4) with plot z of covariance R_z (``predict`` then ``update_models``)."""
    return update_models(*predict(state, models, dt_s), z, rz, models)


def gate_nis(xp: F64, pp: F64, z: F64, rz: F64, widen_m: float) -> float:
    """The manoeuvre gate's statistic from the per-model predictions: min over models of
    nu_j^T (S_j + w^2 I)^-1 nu_j, w = ``widen_m`` = a dt^2 / 2 for an unmodelled acceleration change a over the
    step, i.e. the plot against the most permissive model widened by that manoeuvre."""
    widen = widen_m * widen_m * np.eye(3)
    best = math.inf
    for j in range(xp.shape[0]):
        nu = z - xp[j][POS]
        best = min(best, kalman.nis_solve(nu, pp[j][POS, POS] + rz + widen))
    return best
