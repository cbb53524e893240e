"""Exact evidence of a hypothesis from the whole record: the decision statistic of the ``honest`` preset.

The EKF of section 2.3 accumulates the evidence ln p(Y | u) = -1/2 (A + ln B) of each hypothesis one update at a
time, every range linearised at the predicted state and the heading error linearised about 0 (Eq. 2). In weak
geometry (a track a few degrees off the beacon line) the two hypotheses differ by a few nats over hundreds of
epochs, and these approximation errors are of the same size. This module computes the evidence of one
hypothesis from every range received so far (buffered epochs, launch epoch, current epochs) in one batch:

* unknowns z: per epoch k the state (x_k, y_k, dK_k, dU_N,k, dU_E,k) (the error states only when their sigma
  is not 0), plus the constant sound-speed error dc;
* whitened residuals r(z) of the digest's model (sections 1.3-1.5), all of them Gaussian:
  - priors: dK_0 / sigma_dK, dU_0 / sigma_dU, dc / sigma_dc (no prior on the position: diffuse, as at launch);
  - dead reckoning, Eq. (2) with the heading error applied as an exact rotation of the log displacement
    (ve', vn') = R(dK_k) (ve, vn) (true heading = measured + dK, section 1.4):
    (x_k - x_{k-1} - ve' - U^E dt - dU_E,k dt) / sigma_w and the same for y;
  - the Markov steps (dK_k - a_K dK_{k-1}) / sqrt(q_K), likewise dU (a = exp(-dt/tau), q = sigma^2 (1 - a^2));
  - ranges, Eq. (1): y - D (1 + dc T~/y) with T~/y = 1/c~ (the predicted travel time D/c~ as dc's coefficient),
    whitened per epoch with R = sigma_delta^2 1 1^T + sigma_v^2 I;
* Gauss-Newton (with step halving) from the hypothesis's own EKF estimate, carried back over the record with
  the dead reckoning, to the maximum a posteriori trajectory z*;
* the Laplace approximation of the marginal likelihood at z*:

      ln p(Y | u) = -1/2 |r(z*)|^2 - 1/2 ln det(J^T J) + const,

  J the Jacobian of r at z* (the Gauss-Newton Hessian). The constant (normalisers of the residuals and the
  improper flat position prior) is the same for both hypotheses, so

      ln dp^{1/2} = ln p(Y | u = 1) - ln p(Y | u = 2)

  is the posterior log ratio of rule (6) with equal priors. For a model that is linear in z this is the exact
  marginal likelihood; the range nonlinearity over the posterior width (tens of metres at ranges of hundreds)
  is what remains, and ``tests/test_lbl_nav_evidence.py`` checks the ratio against a brute-force integral of the
  exact likelihood over each half-plane.

The Gauss-Newton Hessian J^T J is banded (epochs couple only with their neighbours) except for the dc row and
column: a banded Cholesky factor of the epoch block and the Schur complement of dc, per iteration about a
millisecond for the paper's N = 360 buffered epochs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.linalg import cho_solve_banded, cholesky_banded

from shared.filters import gauss_markov

from .config import LblNavConfig
from .models import DrIncrement, ErrorModel

F64 = NDArray[np.float64]
#: floor of sigma_w (m) so that a log without noise still gives a finite weight
SIGMA_W_FLOOR_M = 1e-3


@dataclass(frozen=True)
class RangeObs:
    """One range of an epoch: beacon position (m), vehicle depth z (m), the range y (m) and 1/c~ (s/m)."""

    bx: float
    by: float
    bz: float
    z: float
    y: float
    inv_c: float


@dataclass(frozen=True)
class EvidenceEpoch(DrIncrement):
    """One epoch of the record: the integrated DR of (t_{k-1}, t_k] (m), its sigma_w scale and its ranges."""

    ranges: tuple[RangeObs, ...] = ()


@dataclass(frozen=True)
class Priors(ErrorModel):
    """The error model the evidence is computed with (the estimator's configuration by default)."""

    markov_form: str = "exact"
    sigma_w_linear: bool = False

    @classmethod
    def of(cls, cfg: LblNavConfig) -> Priors:
        return cls(
            cfg.sigma_delta_m,
            cfg.sigma_v_m,
            cfg.sigma_dc_mps,
            cfg.sigma_dV_mps,
            cfg.sigma_dK_rad,
            cfg.sigma_dU_mps,
            cfg.tau_dK_s,
            cfg.tau_dU_s,
            cfg.markov_form,
            cfg.sigma_w_form == "linear",
        )


@dataclass(frozen=True)
class Start:
    """Where Gauss-Newton starts: the state at the LAST epoch of the record (the hypothesis's EKF estimate)."""

    x_m: float
    y_m: float
    dc_mps: float = 0.0
    dK_rad: float = 0.0  # noqa: N815
    dU_north_mps: float = 0.0  # noqa: N815
    dU_east_mps: float = 0.0  # noqa: N815


@dataclass
class Fit:
    """Result of :func:`fit`: the MAP state per epoch (columns x, y, dK, dU_N, dU_E; zeros for absent states),
    dc, the cost 1/2 |r|^2, ln det(J^T J) and ln p(Y | u) up to the common constant."""

    X: F64
    dc_mps: float
    cost: float
    logdet: float
    converged: bool
    iterations: int
    z: F64 = field(repr=False)

    @property
    def log_evidence(self) -> float:
        return -self.cost - 0.5 * self.logdet


class _Layout:
    """Column indices of the unknowns: nv per epoch (x, y[, dK][, dU_N, dU_E]) then dc."""

    def __init__(self, n: int, has_k: bool, has_u: bool) -> None:
        self.n = n
        self.has_k, self.has_u = has_k, has_u
        self.iK = 2 if has_k else -1
        self.iUN = (3 if has_k else 2) if has_u else -1
        self.iUE = self.iUN + 1 if has_u else -1
        self.nv = 2 + int(has_k) + 2 * int(has_u)
        self.idc = self.nv * n
        self.size = self.idc + 1

    def col(self, k: F64 | NDArray[np.int64] | int, j: int) -> NDArray[np.int64]:
        return np.asarray(k, dtype=np.int64) * self.nv + j


class Record:
    """The epochs of one hypothesis test as arrays (shared by both hypotheses)."""

    def __init__(self, epochs: list[EvidenceEpoch], pri: Priors) -> None:
        if not epochs:
            raise ValueError("empty record")
        self.n = n = len(epochs)
        self.pri = pri
        self.dt = np.array([e.dt_s for e in epochs])
        self.ve = np.array([e.ve_dt_m for e in epochs])
        self.vn = np.array([e.vn_dt_m for e in epochs])
        self.ue = np.array([e.ue_dt_m for e in epochs])
        self.un = np.array([e.un_dt_m for e in epochs])
        w2 = pri.sigma_dV_mps**2 * (self.dt * self.dt if pri.sigma_w_linear else self.dt)
        self.sw = np.maximum(np.sqrt(w2) * np.array([e.sigma_w_scale for e in epochs]), SIGMA_W_FLOOR_M)
        self.layout = _Layout(n, pri.sigma_dK_rad > 0.0, pri.sigma_dU_mps > 0.0)
        aK = [gauss_markov.discretise(dt, pri.tau_dK_s, pri.sigma_dK_rad, pri.markov_form) for dt in self.dt[1:]]
        aU = [gauss_markov.discretise(dt, pri.tau_dU_s, pri.sigma_dU_mps, pri.markov_form) for dt in self.dt[1:]]
        self.aK = np.array([a for a, _ in aK])
        self.sqK = np.sqrt(np.maximum(np.array([q for _, q in aK]), 1e-30))
        self.aU = np.array([a for a, _ in aU])
        self.sqU = np.sqrt(np.maximum(np.array([q for _, q in aU]), 1e-30))
        # ranges grouped by their number per epoch (the same whitening matrix for every epoch of a group)
        self.groups: list[tuple[NDArray[np.int64], F64, F64]] = []
        by_m: dict[int, list[int]] = {}
        for k, e in enumerate(epochs):
            if e.ranges:
                by_m.setdefault(len(e.ranges), []).append(k)
        self.n_ranges = 0
        for m, ks in sorted(by_m.items()):
            obs = np.array([[(r.bx, r.by, r.bz, r.z, r.y, r.inv_c) for r in epochs[k].ranges] for k in ks])
            R = pri.sigma_delta_m**2 * np.ones((m, m)) + pri.sigma_v_m**2 * np.eye(m)
            W = np.linalg.inv(np.linalg.cholesky(R))  # whitening: W R W^T = I
            self.groups.append((np.array(ks, dtype=np.int64), obs, W))
            self.n_ranges += m * len(ks)

    def start(self, s: Start) -> F64:
        """Initial z: the last epoch's state carried back over the record with the dead reckoning."""
        L, n = self.layout, self.n
        z = np.zeros(L.size)
        X = z[: L.idc].reshape(n, L.nv)
        c, s_ = math.cos(s.dK_rad), math.sin(s.dK_rad)
        step_x = self.ve * c + self.vn * s_ + self.ue + s.dU_east_mps * self.dt
        step_y = self.vn * c - self.ve * s_ + self.un + s.dU_north_mps * self.dt
        # x_{k-1} = x_k - step_k: reverse cumulative sums of the steps of epochs k+1..n-1
        tail_x = np.concatenate([np.cumsum(step_x[:0:-1])[::-1], [0.0]])
        tail_y = np.concatenate([np.cumsum(step_y[:0:-1])[::-1], [0.0]])
        X[:, 0] = s.x_m - tail_x
        X[:, 1] = s.y_m - tail_y
        if L.has_k:
            X[:, L.iK] = s.dK_rad
        if L.has_u:
            X[:, L.iUN] = s.dU_north_mps
            X[:, L.iUE] = s.dU_east_mps
        z[L.idc] = s.dc_mps
        return z

    def extend(self, z_prev: F64, n_prev: int) -> F64:
        """A start for this record from a fit of its first ``n_prev`` epochs: those states kept, the later ones
        carried forwards from the last fitted state with the dead reckoning (error states held)."""
        L, n = self.layout, self.n
        if n_prev > n or z_prev.size != n_prev * L.nv + 1:
            raise ValueError("z_prev does not fit this record")
        z = np.zeros(L.size)
        X = z[: L.idc].reshape(n, L.nv)
        X[:n_prev] = z_prev[:-1].reshape(n_prev, L.nv)
        z[L.idc] = z_prev[-1]
        last = X[n_prev - 1].copy()
        K = float(last[L.iK]) if L.has_k else 0.0
        UN = float(last[L.iUN]) if L.has_u else 0.0
        UE = float(last[L.iUE]) if L.has_u else 0.0
        c, s_ = math.cos(K), math.sin(K)
        for k in range(n_prev, n):
            last[0] += self.ve[k] * c + self.vn[k] * s_ + self.ue[k] + UE * self.dt[k]
            last[1] += self.vn[k] * c - self.ve[k] * s_ + self.un[k] + UN * self.dt[k]
            X[k] = last
        return z

    def residuals(self, z: F64, jac: bool = True) -> tuple[F64, sp.csr_matrix | None]:
        """Whitened residuals r(z) and (optionally) their sparse Jacobian."""
        L, n, pri = self.layout, self.n, self.pri
        X = z[: L.idc].reshape(n, L.nv)
        dc = float(z[L.idc])
        x, y = X[:, 0], X[:, 1]
        zeros = np.zeros(n)
        K = X[:, L.iK] if L.has_k else zeros
        UN = X[:, L.iUN] if L.has_u else zeros
        UE = X[:, L.iUE] if L.has_u else zeros
        res: list[F64] = []
        rows: list[NDArray[np.int64]] = []
        cols: list[NDArray[np.int64]] = []
        vals: list[F64] = []
        row0 = 0

        def add(r: F64, entries: list[tuple[NDArray[np.int64], F64]]) -> None:
            nonlocal row0
            idx = np.arange(row0, row0 + r.size, dtype=np.int64)
            res.append(r)
            if jac:
                for c, v in entries:
                    rows.append(idx)
                    cols.append(np.broadcast_to(c, r.shape).astype(np.int64))
                    vals.append(np.broadcast_to(v, r.shape).astype(np.float64))
            row0 += r.size

        one = np.ones(1)
        # priors at the first epoch (no position prior: diffuse)
        if L.has_k:
            add(np.array([K[0] / pri.sigma_dK_rad]), [(L.col(0, L.iK), one / pri.sigma_dK_rad)])
        if L.has_u:
            add(np.array([UN[0] / pri.sigma_dU_mps]), [(L.col(0, L.iUN), one / pri.sigma_dU_mps)])
            add(np.array([UE[0] / pri.sigma_dU_mps]), [(L.col(0, L.iUE), one / pri.sigma_dU_mps)])
        add(np.array([dc / pri.sigma_dc_mps]), [(np.array([L.idc]), one / pri.sigma_dc_mps)])
        if n > 1:
            k = np.arange(1, n)
            sw, dt = self.sw[1:], self.dt[1:]
            c, s_ = np.cos(K[1:]), np.sin(K[1:])
            ve, vn = self.ve[1:], self.vn[1:]
            ver = ve * c + vn * s_  # R(dK) (ve, vn): true heading = measured + dK
            vnr = vn * c - ve * s_
            rx = (x[1:] - x[:-1] - ver - self.ue[1:] - UE[1:] * dt) / sw
            ry = (y[1:] - y[:-1] - vnr - self.un[1:] - UN[1:] * dt) / sw
            ex = [(L.col(k, 0), 1.0 / sw), (L.col(k - 1, 0), -1.0 / sw)]
            ey = [(L.col(k, 1), 1.0 / sw), (L.col(k - 1, 1), -1.0 / sw)]
            if L.has_k:  # d ver / d dK = vnr, d vnr / d dK = -ver
                ex.append((L.col(k, L.iK), -vnr / sw))
                ey.append((L.col(k, L.iK), ver / sw))
            if L.has_u:
                ex.append((L.col(k, L.iUE), -dt / sw))
                ey.append((L.col(k, L.iUN), -dt / sw))
            add(rx, ex)
            add(ry, ey)
            if L.has_k:
                add(
                    (K[1:] - self.aK * K[:-1]) / self.sqK,
                    [(L.col(k, L.iK), 1.0 / self.sqK), (L.col(k - 1, L.iK), -self.aK / self.sqK)],
                )
            if L.has_u:
                for j, U in ((L.iUN, UN), (L.iUE, UE)):
                    add(
                        (U[1:] - self.aU * U[:-1]) / self.sqU,
                        [(L.col(k, j), 1.0 / self.sqU), (L.col(k - 1, j), -self.aU / self.sqU)],
                    )
        # ranges (1): h = D (1 + dc / c~); whitened per epoch
        for ks, obs, W in self.groups:
            ex_ = x[ks][:, None] - obs[:, :, 0]
            ey_ = y[ks][:, None] - obs[:, :, 1]
            ez_ = obs[:, :, 3] - obs[:, :, 2]
            D = np.sqrt(ex_ * ex_ + ey_ * ey_ + ez_ * ez_)
            f = 1.0 + dc * obs[:, :, 5]
            e = obs[:, :, 4] - D * f
            hx, hy, hdc = ex_ / D * f, ey_ / D * f, D * obs[:, :, 5]
            ew = e @ W.T  # (n_epochs, m)
            hxw, hyw, hdcw = hx @ W.T, hy @ W.T, hdc @ W.T
            kk = np.repeat(ks, e.shape[1])
            # residual r = -(whitened e) so that dr/dz = +whitened dh/dz
            add(
                -ew.ravel(),
                [(L.col(kk, 0), hxw.ravel()), (L.col(kk, 1), hyw.ravel()), (np.array([L.idc]), hdcw.ravel())],
            )
        r = np.concatenate(res)
        if not jac:
            return r, None
        J = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(row0, L.size))
        return r, J


class _Normal:
    """Cholesky of the Gauss-Newton Hessian H = J^T J = [[A, b], [b^T, c]]: A (the epochs' states) banded with
    ``bw`` bands above the diagonal, the last variable (dc) dense. Solves H d = g and gives ln det H."""

    def __init__(self, J: sp.csr_matrix, bw: int) -> None:
        H = (J.T @ J).tocoo()
        n = H.shape[0] - 1
        m = (H.row < n) & (H.col < n) & (H.col >= H.row)
        ab = np.zeros((bw + 1, n))
        np.add.at(ab, (bw + H.row[m] - H.col[m], H.col[m]), H.data[m])
        last = H.col == n
        self.b = np.zeros(n)
        np.add.at(self.b, H.row[last & (H.row < n)], H.data[last & (H.row < n)])
        self.c = float(np.sum(H.data[last & (H.row == n)]))
        self.U = cholesky_banded(ab, lower=False)
        self.Ainv_b = cho_solve_banded((self.U, False), self.b)
        self.s = self.c - float(self.b @ self.Ainv_b)  # Schur complement of dc
        if not self.s > 0.0:
            raise np.linalg.LinAlgError("Gauss-Newton Hessian is not positive definite")
        self.n = n

    def solve(self, g: F64) -> F64:
        ga, gc = g[: self.n], float(g[self.n])
        ya = cho_solve_banded((self.U, False), ga)
        d_c = (gc - float(self.b @ ya)) / self.s
        return np.concatenate([ya - self.Ainv_b * d_c, [d_c]])

    def logdet(self) -> float:
        return 2.0 * float(np.sum(np.log(self.U[-1]))) + math.log(self.s)


def fit(rec: Record, start: Start, max_iter: int = 20, tol: float = 1e-6, z0: F64 | None = None) -> Fit:
    """Gauss-Newton with step halving from ``start`` (or from ``z0``, e.g. the previous fit extended by
    :meth:`Record.extend`) to the MAP trajectory of one hypothesis."""
    z = rec.start(start) if z0 is None else z0.copy()
    bw = 2 * rec.layout.nv - 1
    r, J = rec.residuals(z)
    assert J is not None
    cost = 0.5 * float(r @ r)
    converged = False
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007
        g = J.T @ r
        step = -_Normal(J, bw).solve(g)
        if not np.all(np.isfinite(step)):
            raise np.linalg.LinAlgError("Gauss-Newton step is not finite")
        alpha, accepted = 1.0, False
        for _ in range(30):
            z_new = z + alpha * step
            r_new, _ = rec.residuals(z_new, jac=False)
            cost_new = 0.5 * float(r_new @ r_new)
            if np.isfinite(cost_new) and cost_new <= cost:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            break
        decrease = cost - cost_new
        z = z_new
        r, J = rec.residuals(z)
        assert J is not None
        cost = 0.5 * float(r @ r)
        if alpha == 1.0 and (decrease <= tol * max(1.0, cost) or float(np.max(np.abs(step))) < 1e-6):
            converged = True
            break
    logdet = _Normal(J, bw).logdet()
    if not math.isfinite(logdet):
        raise np.linalg.LinAlgError("singular Gauss-Newton Hessian")
    L = rec.layout
    X = np.zeros((rec.n, 5))
    Z = z[: L.idc].reshape(rec.n, L.nv)
    X[:, 0], X[:, 1] = Z[:, 0], Z[:, 1]
    if L.has_k:
        X[:, 2] = Z[:, L.iK]
    if L.has_u:
        X[:, 3], X[:, 4] = Z[:, L.iUN], Z[:, L.iUE]
    return Fit(X, float(z[L.idc]), cost, logdet, converged, it, z)


def predicted_ranges(rec: Record, f: Fit) -> list[F64]:
    """The ranges the fitted trajectory predicts, per group of :attr:`Record.groups` (noise-free data)."""
    out = []
    for ks, obs, _ in rec.groups:
        ex_ = f.X[ks, 0][:, None] - obs[:, :, 0]
        ey_ = f.X[ks, 1][:, None] - obs[:, :, 1]
        ez_ = obs[:, :, 3] - obs[:, :, 2]
        out.append(np.sqrt(ex_ * ex_ + ey_ * ey_ + ez_ * ez_) * (1.0 + f.dc_mps * obs[:, :, 5]))
    return out


def with_ranges(rec: Record, values: list[F64]) -> Record:
    """A copy of ``rec`` whose range values are replaced (group by group)."""
    new = object.__new__(Record)
    new.__dict__.update(rec.__dict__)
    groups = []
    for (ks, obs, W), v in zip(rec.groups, values, strict=True):
        o = obs.copy()
        o[:, :, 4] = v
        groups.append((ks, o, W))
    new.groups = groups
    return new
