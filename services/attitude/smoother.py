"""Fixed-lag smoothing of the IMM (issue 15): the estimate of the plot L scans back, given the plots up to now.

The real-time filter cannot use later plots; an estimate delayed by L scans can. Here every model's state of the
IMM (:mod:`.imm`) is augmented with its last L 9-states, y_j = [alpha_j(t_k), alpha_j9(t_k-1), ..,
alpha_j9(t_k-L)] (state augmentation; Bar-Shalom, Li & Kirubarajan 2001, §8.7 for one model; for the IMM e.g.
Chen & Tugnait, "Interacting multiple model fixed-lag smoothing algorithm for Markovian switching systems",
IEEE T-AES 36(1), 2000, whose augmented-state form this is). The IMM cycle runs unchanged on the augmented states:

1. mixing with the same weights mu_i|j on the whole augmented state (the lagged blocks mixed like the current);
2. prediction: the current block by the model's own prediction, the lagged blocks shifted by one (the current
   9-state before the step becomes lag 1, lag L is dropped); what is new is the cross-covariance of the predicted
   current state with the shifted lags: F cov(alpha, y) for the linear (CA, Singer) models and the CT model's EKF;
   for the CT model's quadrature over the turn rate the E_omega[Phi(omega) ...] moment of
   :func:`~.models.ct_cross_covariance` (the same Gauss-Hermite nodes as the prediction itself);
3. update with the plot's H on the current positions: the lagged blocks get the gain K_lag = cov(lag, alpha~) H^T
   S^-1 of the same innovation;
4. the CA/Singer models' implied turn rate (:func:`~.imm.augment`) is re-derived after the update, its covariance
   with the lags s g^T cov(alpha9, lag).

The current block and the model probabilities ARE the real-time IMM's: this module never recomputes them, it takes
them from the IMM cycle (:func:`step` gets the cycle's predictions and result) and adds only the lagged blocks, so
turning the smoother on cannot change a real-time output. The smoothed estimate of lag l is the mixture over the
models of block l with the current probabilities mu_j(t_k) (the augmented IMM's output), a 9-state (x, P).

With one linear model this is the Rauch-Tung-Striebel smoother's estimate of alpha(t_k-L) given the plots up to t_k
(``tests/test_attitude_smoother.py`` checks it against filterpy's ``rts_smoother``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from shared.filters.covariance import symmetrize

from .config import MotionModel
from .geometry import F64
from .imm import ImmState, combine, implied_turn_rate, mixing_weights, model_matrices, transition_matrix
from .models import OMEGA, POS, ct_cross_covariance, ct_step

N9 = 9


@dataclass
class LagState:
    """The lagged blocks of every model's augmented state: xl (M, 9l) the 9-states at the l previous plots, newest
    first; pl (M, 9l, 9l) their covariance; pc (M, 9l, n) their covariance with the model's current state (n = 9
    or 10, :func:`~.imm.state_dim`); stamps (l,) the plots' stamps, newest first. l grows to the lag after a
    start."""

    xl: F64
    pl: F64
    pc: F64
    stamps: tuple[int, ...]

    @classmethod
    def empty(cls, n_models: int, n: int) -> LagState:
        return cls(np.zeros((n_models, 0)), np.zeros((n_models, 0, 0)), np.zeros((n_models, 0, n)), ())

    @property
    def depth(self) -> int:
        return len(self.stamps)

    def smoothed(self, mu: F64, lag: int) -> tuple[int, F64, F64]:
        """(stamp, x (9,), P (9x9)) of lag ``lag`` (1..depth): the mixture of the models' lagged block with the
        current model probabilities mu."""
        a, b = N9 * (lag - 1), N9 * lag
        x, p = combine(self.xl[:, a:b], self.pl[:, a:b, a:b], mu)
        return self.stamps[lag - 1], x, p


def _cross_prediction(model: MotionModel, x0: F64, p0: F64, b: F64, dt_s: float) -> F64:
    """cov(alpha~_j, y) of model j's predicted current state with the shifted lag vector y, given its mixed start
    (x0, P0) and B = cov(alpha0, y) (n x K)."""
    if model.kind == "ct":
        assert model.sigma_accel_mps2 is not None and model.tau_s is not None
        if model.ct_prediction == "quadrature":
            return ct_cross_covariance(x0, p0, b, dt_s, model.sigma_accel_mps2, model.tau_s)
        f = ct_step(x0, dt_s, model.sigma_accel_mps2, model.tau_s, model.q_omega)[1]
        return np.asarray(f @ b, dtype=np.float64)
    f, _ = model_matrices(model, dt_s)
    out = np.empty_like(b)
    out[:N9] = f @ b[:N9]
    if b.shape[0] > N9:  # the implied turn rate is carried along unchanged by the prediction (imm.predict)
        out[N9:] = b[N9:]
    return out


def step(
    lag: LagState,
    prev: ImmState,
    models: tuple[MotionModel, ...],
    dt_s: float,
    xp: F64,
    pp: F64,
    z: F64,
    rz: F64,
    new: ImmState,
    t_prev_ns: int,
    max_lag: int,
) -> LagState:
    """The lagged blocks after one IMM cycle: ``prev`` the IMM state before it (at ``t_prev_ns``), (xp, pp) the
    cycle's per-model predictions (:func:`~.imm.predict`), (z, R_z) the plot, ``new`` the cycle's result
    (:func:`~.imm.update_models`). Raises numpy.linalg.LinAlgError if an innovation covariance is not positive
    definite (never when the IMM's update succeeded: it is the same S)."""
    m, n = prev.xs.shape
    d_old = lag.depth
    d_new = min(d_old + 1, max_lag)
    keep = N9 * (d_new - 1)  # old lag components that stay (shifted by one block)
    k_new = N9 * d_new
    # 1. mixing of the lagged blocks with the IMM's weights
    _, w = mixing_weights(prev.mu, transition_matrix(prev, models, float(dt_s)))
    x0 = w.T @ prev.xs
    xl0 = w.T @ lag.xl
    xl_out = np.empty((m, k_new))
    pl_out = np.empty((m, k_new, k_new))
    pc_out = np.empty((m, k_new, n))
    for j in range(m):
        dc = prev.xs - x0[j]
        dl = lag.xl - xl0[j]
        wj = w[:, j]
        p0 = np.einsum("i,ikl->kl", wj, prev.ps) + (dc.T * wj) @ dc
        pl0 = np.einsum("i,ikl->kl", wj, lag.pl) + (dl.T * wj) @ dl
        pc0 = np.einsum("i,ikl->kl", wj, lag.pc) + (dl.T * wj) @ dc  # cov(lag, current) (9 d_old, n)
        # 2. prediction: y = [alpha0_9, lags 1..d_new-1]; its covariance, and the new current's with it
        y = np.concatenate([x0[j, :N9], xl0[j, :keep]])
        pyy = np.empty((k_new, k_new))
        pyy[:N9, :N9] = p0[:N9, :N9]
        pyy[N9:, :N9] = pc0[:keep, :N9]
        pyy[:N9, N9:] = pc0[:keep, :N9].T
        pyy[N9:, N9:] = pl0[:keep, :keep]
        b = np.concatenate([p0[:, :N9], pc0[:keep].T], axis=1)  # cov(alpha0, y) (n, k_new)
        cross = _cross_prediction(models[j], x0[j], p0, b, float(dt_s)).T  # cov(y, alpha~) (k_new, n)
        # 3. update with the plot: the same innovation and S as the model's own update
        s = pp[j][POS, POS] + rz
        fac = cho_factor(s, lower=True)
        kh = cross[:, POS]  # cov(y, H alpha~)
        gain = cho_solve(fac, kh.T).T  # (k_new, 3)
        xl_out[j] = y + gain @ (z - xp[j][POS])
        pl_out[j] = symmetrize(pyy - gain @ kh.T)
        pcj = cross - gain @ pp[j][POS, :]
        # 4. the CA/Singer models' implied turn rate, re-derived from the updated state (imm.augment)
        if n > N9 and models[j].kind != "ct":
            _, g, _, _, sc = implied_turn_rate(new.xs[j], new.ps[j])
            pcj[:, OMEGA] = sc * (pcj[:, :N9] @ g)
        pc_out[j] = pcj
    stamps = (t_prev_ns, *lag.stamps)[:d_new]
    return LagState(xl_out, pl_out, pc_out, stamps)
