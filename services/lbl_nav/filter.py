"""Per-hypothesis EKF (2.3), gradual backward processing of buffered epochs through the augmented state
(Eq. 5, Fig. 4, 2.4), common innovation gating (5.4), the posterior ratio, decision rule (6) and merge (2.5).

``HypothesisBank`` runs every live hypothesis in lock-step so that all of them process exactly the same
measurements in the same order (test U12); it is generic in the measurement rows (``models.Row``).
"""

from __future__ import annotations

import math
import zlib
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from shared.filters import kalman
from shared.filters.covariance import symmetrize

from .config import LblNavConfig
from .decision import ExactCheck, ExactDecision, evidence_epoch, start_of
from .models import AUG, COPY_IDX, F64, IDC, IDK, IX, IY, SDK, DrInterval, MotionModel, Row, noise_cov

ROW_LOG_MAX = 20_000


@dataclass
class BufferedEpoch:
    """One stored epoch s < 0: the DR of (t_{s-1}, t_s] and at most one range (a vector if launch was postponed)."""

    k: int
    stamp_ns: int
    dr: DrInterval
    rows: list[Row] = field(default_factory=list)
    depth_m: float | None = None


class HypothesisFilter:
    """EKF of one hypothesis u on X (6 states) or the augmented X_{s,i} (11 states)."""

    def __init__(self, hyp_id: int, X: F64, P: F64, A: float = 0.0, lnB: float = 0.0) -> None:
        self.hyp_id = hyp_id
        self.X = np.array(X, dtype=np.float64)
        self.P = np.array(P, dtype=np.float64)
        self.A = A  # sum of nu^T S^-1 nu
        self.lnB = lnB  # sum of ln det S
        self.n_rows = 0
        self.crc = 0
        self.row_log: deque[tuple[int, str]] = deque(maxlen=ROW_LOG_MAX)

    @property
    def augmented(self) -> bool:
        return self.X.size == 11

    def idx(self, block: str) -> tuple[int, int, int]:
        """Indices of (x, y, dc) used by a row of the buffered ('s') or current ('i') block."""
        if self.augmented:
            return (0, 1, AUG + IDC) if block == "s" else (AUG + IX, AUG + IY, AUG + IDC)
        if block == "s":
            raise ValueError("a buffered row needs the augmented state")
        return IX, IY, IDC

    def current(self) -> tuple[F64, F64]:
        """X_i and its 6x6 covariance (the last six components when augmented)."""
        if self.augmented:
            return self.X[AUG:], self.P[AUG:, AUG:]
        return self.X, self.P

    # ---- augmentation ------------------------------------------------------------------------------------------
    def augment(self) -> None:
        """[R] X_{0,0} = J X_0, P_{0,0} = J P_0 J^T with J = [S; I_6]: copy and original fully correlated."""
        J = np.zeros((11, 6))
        for r, c in enumerate(COPY_IDX):
            J[r, c] = 1.0
        J[AUG:, :] = np.eye(6)
        self.X = J @ self.X
        self.P = J @ self.P @ J.T

    def drop_augmentation(self) -> None:
        """s reached -N: keep the last six components and their 6x6 block."""
        self.X = self.X[AUG:].copy()
        self.P = self.P[AUG:, AUG:].copy()

    # ---- prediction --------------------------------------------------------------------------------------------
    def predict_forward(self, Phi: F64, b: F64, Q: F64) -> None:
        self.X, self.P = kalman.predict(self.X, self.P, Phi, Q, b)

    def predict_backward(self, Phib: F64, bb: F64, Qb: F64) -> None:
        """Step of kind 1: the buffered copy goes back s+1 -> s, X_i untouched (identity, no noise)."""
        X, P = self.X, self.P
        X[:AUG] = Phib @ X[:AUG] + bb
        top = Phib @ P[:AUG, :]
        P[:AUG, :] = top
        P[:, :AUG] = P[:, :AUG] @ Phib.T
        P[:AUG, :AUG] += Qb
        self.P = symmetrize(P)

    def predict_joint(self, Phib: F64, bb: F64, Qb: F64, Phi: F64, b: F64, Q: F64) -> None:
        """Step of kind 2: copy backwards and X_i forwards; block-diagonal transition."""
        F = np.zeros((11, 11))
        F[:AUG, :AUG] = Phib
        F[AUG:, AUG:] = Phi
        Qa = np.zeros((11, 11))
        Qa[:AUG, :AUG] = Qb
        Qa[AUG:, AUG:] = Q
        self.X = np.concatenate([Phib @ self.X[:AUG] + bb, Phi @ self.X[AUG:] + b])
        self.P = symmetrize(F @ self.P @ F.T + Qa)

    # ---- update ------------------------------------------------------------------------------------------------
    def innovations(self, rows: list[Row], second_order: bool = False) -> tuple[F64, F64, F64]:
        """nu = Y - h(X^-), H = dh/dX at X^- and the extra variance of each row (zero for a plain EKF).

        [IMPL] ``second_order``: Gaussian second-order correction of the range nonlinearity, h += 1/2 tr(Hess P)
        and variance += 1/2 tr((Hess P)^2) with the horizontal position block of P."""
        m, n = len(rows), self.X.size
        nu = np.empty(m)
        extra = np.zeros(m)
        H = np.zeros((m, n))
        for r, row in enumerate(rows):
            nu[r], extra[r], H[r] = self.innovation(row, second_order)
        return nu, H, extra

    def innovation(self, row: Row, second_order: bool = False) -> tuple[float, float, F64]:
        """One row of :meth:`innovations`: (nu, extra variance, the row of H)."""
        px, py, pdc = self.idx(row.block)
        X = self.X
        x, y = float(X[px]), float(X[py])
        h, hx, hy, hdc = row.predict(x, y, float(X[pdc]))
        extra = 0.0
        if second_order:
            P = self.P
            a, b, c = row.hessian_xy(x, y)
            pxx, pxy, pyy = P[px, px], P[px, py], P[py, py]
            h += 0.5 * (a * pxx + 2.0 * b * pxy + c * pyy)
            # (Hess P) = [[a pxx + b pxy, a pxy + b pyy], [b pxx + c pxy, b pxy + c pyy]]
            m00, m01 = a * pxx + b * pxy, a * pxy + b * pyy
            m10, m11 = b * pxx + c * pxy, b * pxy + c * pyy
            extra = float(0.5 * (m00 * m00 + 2.0 * m01 * m10 + m11 * m11))
        Hr = np.zeros(X.size)
        Hr[px] = hx
        Hr[py] = hy
        Hr[pdc] = hdc
        return float(row.value - h), extra, Hr

    def update(self, nu: F64, H: F64, R: F64, rows: list[Row], iterations: int = 1) -> None:
        """Joseph-form EKF update; accumulates A += nu^T S^-1 nu and ln B += ln det S.

        [IMPL] ``iterations`` > 1: iterated EKF (Gauss-Newton relinearisation of the rows at the updated state;
        nu and H are then taken at the last linearisation point)."""
        P = self.P
        if iterations > 1:
            x_prior = self.X
            x_j = x_prior
            for _ in range(iterations - 1):
                PHt = P @ H.T
                S = H @ PHt + R
                x_j = x_prior + PHt @ np.linalg.solve(S, nu)
                self.X = x_j
                nu_j, H, _ = self.innovations(rows)
                nu = nu_j - H @ (x_prior - x_j)
            self.X = x_prior
        if H.shape[0] == 1:
            self._update_scalar(float(nu[0]), H[0], float(R[0, 0]), rows)
            return
        PHt = P @ H.T
        S = H @ PHt + R
        m = S.shape[0]
        if m == 1:
            s = float(S[0, 0])
            if not s > 0.0:
                raise np.linalg.LinAlgError("innovation variance is not positive")
            K = PHt / s
            a = float(nu[0]) ** 2 / s
            logdet = math.log(s)
        else:
            S = symmetrize(S)
            L = np.linalg.cholesky(S)
            Sinv = np.linalg.inv(S)
            K = PHt @ Sinv
            a = float(nu @ Sinv @ nu)
            logdet = 2.0 * float(np.sum(np.log(np.diag(L))))
        self.X = self.X + K @ nu
        self.P = kalman.joseph(P, K, H, R)
        self.A += a
        self.lnB += logdet
        self._log_rows(rows)

    def _update_scalar(self, nu: float, h: F64, r: float, rows: list[Row]) -> None:
        """The Joseph-form update of :meth:`update` for one row (the usual case), on 1-D vectors: the same
        products as the (n, 1) and (1, n) matrices (each entry of an outer product is one product), without the
        matrix-vector call overhead. ``h`` is the row of H, ``r`` the variance of the row."""
        P = self.P
        PHt = P @ h
        s = float(h @ PHt) + r
        if not s > 0.0:
            raise np.linalg.LinAlgError("innovation variance is not positive")
        K = PHt / s
        self.X = self.X + K * nu
        IKH = _eye(P.shape[0]) - K[:, None] * h
        self.P = symmetrize(IKH @ P @ IKH.T + (K * r)[:, None] * K)
        self.A += nu**2 / s
        self.lnB += math.log(s)
        self._log_rows(rows)

    def _log_rows(self, rows: list[Row]) -> None:
        for row in rows:
            self.n_rows += 1
            self.row_log.append((row.stamp_ns, row.key))
            self.crc = zlib.crc32(f"{row.stamp_ns}:{row.key};".encode(), self.crc)


_EYE: dict[int, F64] = {}


def _eye(n: int) -> F64:
    e = _EYE.get(n)
    if e is None:
        e = _EYE[n] = np.eye(n)
        e.flags.writeable = False
    return e


@dataclass
class StepReport:
    """What one lock-step update did with the rows of the current epoch."""

    used_current: int = 0
    rejected_current: int = 0
    rejected_buffered: int = 0
    rejected_keys: list[str] = field(default_factory=list)
    kept_current: list[Row] = field(default_factory=list)


@dataclass
class Decision:
    kind: str  # "decision" or "merge"
    hypothesis_id: int | None
    log_ratio: float
    exact: ExactCheck | None = None


class HypothesisBank:
    """All live hypotheses of one vehicle plus the shared buffered-processing schedule (s, N, Delta N)."""

    def __init__(
        self,
        cfg: LblNavConfig,
        motion: MotionModel,
        hyps: list[HypothesisFilter],
        buffer: list[BufferedEpoch],
        launch_dr: DrInterval | None,
        launch_rows: list[Row] | None = None,
    ) -> None:
        self.cfg = cfg
        self.motion = motion
        self.hyps = list(hyps)
        self.buffer = list(buffer) if launch_dr is not None else []
        self.N = len(self.buffer)
        self.processed = 0  # = -s
        self._launch_dr = launch_dr
        self.gate = float(chi2.ppf(cfg.gate_prob, 1))
        self.decided: int | None = None
        self.merged = False
        #: the EKF's ln dp when a decision was made (the exact rule decides on another value)
        self.log_ratio_at_decision: float | None = None
        #: the honest preset's exact evidence of the whole record (two hypotheses only)
        self.exact: ExactDecision | None = None
        if cfg.decision_statistic == "exact" and len(self.hyps) == 2 and launch_dr is not None:
            self.exact = ExactDecision(
                cfg,
                [evidence_epoch(e.dr, e.rows) for e in self.buffer] + [evidence_epoch(launch_dr, launch_rows or [])],
            )
        if self.N > 0:
            for h in self.hyps:
                h.augment()

    # ---- schedule ----------------------------------------------------------------------------------------------
    @property
    def catching_up(self) -> bool:
        return self.processed < self.N

    @property
    def augmented(self) -> bool:
        return self.hyps[0].augmented

    def _next_entry(self) -> tuple[DrInterval, BufferedEpoch]:
        """Buffered epoch s = -(processed+1) and the DR of (t_s, t_{s+1}] for the backward step."""
        j = self.N - 1 - self.processed
        dr = self._launch_dr if j == self.N - 1 else self.buffer[j + 1].dr
        assert dr is not None
        return dr, self.buffer[j]

    def _finish_buffer(self) -> None:
        if self.augmented and self.processed >= self.N:
            for h in self.hyps:
                h.drop_augmentation()
            self.buffer = []

    def _backward(self, dr: DrInterval) -> tuple[F64, F64, F64] | None:
        """The backward matrices shared by every hypothesis (None: they depend on each one's dK estimate)."""
        return None if self.cfg.heading_linearisation == "estimate" else self.motion.backward(dr)

    def _forward(self, dr: DrInterval) -> tuple[F64, F64, F64] | None:
        """The forward matrices shared by every hypothesis (None: they depend on each one's dK estimate)."""
        return None if self.cfg.heading_linearisation == "estimate" else self.motion.forward(dr)

    def _back_step(self, report: StepReport) -> None:
        dr, entry = self._next_entry()
        shared = self._backward(dr)
        for h in self.hyps:
            Phib, bb, Qb = shared or self.motion.backward(dr, float(h.X[SDK]))
            h.predict_backward(Phib, bb, Qb)
        self.processed += 1
        self.update_all(list(entry.rows), report)

    def launch_steps(self) -> StepReport:
        """At i = 0: Delta N_0 buffered epochs (s = -1 ... -Delta N_0)."""
        return self.process_buffered(self.cfg.dN0)

    def process_buffered(self, count: int) -> StepReport:
        """Up to ``count`` steps of kind 1 (backward prediction and update with Y_s only)."""
        report = StepReport()
        for _ in range(min(count, self.N - self.processed)):
            self._back_step(report)
        self._finish_buffer()
        return report

    def epoch_step(self, dr: DrInterval, rows: list[Row]) -> StepReport:
        """Epoch i >= 1: joint step with Y_i (kind 2) then Delta N - 1 buffered steps (kind 1), or a plain EKF step."""
        report = StepReport()
        if self.augmented:
            drb, entry = self._next_entry()
            back, fwd = self._backward(drb), self._forward(dr)
            for h in self.hyps:
                Phib, bb, Qb = back or self.motion.backward(drb, float(h.X[SDK]))
                Phi, b, Q = fwd or self.motion.forward(dr, float(h.X[AUG + IDK]))
                h.predict_joint(Phib, bb, Qb, Phi, b, Q)
            self.processed += 1
            self.update_all(list(entry.rows) + list(rows), report)
            for _ in range(self.cfg.dN - 1):
                if not self.catching_up:
                    break
                self._back_step(report)
            self._finish_buffer()
        else:
            fwd = self._forward(dr)
            for h in self.hyps:
                Phi, b, Q = fwd or self.motion.forward(dr, float(h.X[IDK]))
                h.predict_forward(Phi, b, Q)
            self.update_all(list(rows), report)
        if self.exact is not None and len(self.hyps) == 2:
            self.exact.append(dr, report.kept_current)
        return report

    # ---- common gating and update ----------------------------------------------------------------------------
    def update_all(self, rows: list[Row], report: StepReport) -> None:
        """Reject a row only if it is an outlier under every live hypothesis; then all hypotheses drop it."""
        if not rows:
            return
        if len(rows) == 1:
            self._update_one(rows[0], report)
            return
        cfg = self.cfg
        R = noise_cov([r.group for r in rows], cfg.sigma_delta_m, cfg.sigma_v_m)
        r_diag = cfg.sigma_delta_m**2 + cfg.sigma_v_m**2
        per_hyp = []
        outlier_everywhere = np.ones(len(rows), dtype=bool)
        so = cfg.second_order
        for h in self.hyps:
            nu, H, extra = h.innovations(rows, so)
            s_diag = ((H @ h.P) * H).sum(axis=1) + r_diag + extra
            outlier_everywhere &= nu * nu > self.gate * s_diag
            per_hyp.append((nu, H, extra))
        keep = ~outlier_everywhere
        for r, row in enumerate(rows):
            if row.block == "i":
                if keep[r]:
                    report.used_current += 1
                    report.kept_current.append(row)
                else:
                    report.rejected_current += 1
            elif not keep[r]:
                report.rejected_buffered += 1
            if not keep[r]:
                report.rejected_keys.append(f"{row.stamp_ns}:{row.key}")
        if not keep.any():
            return
        if keep.all():
            for h, (nu, H, extra) in zip(self.hyps, per_hyp, strict=True):
                h.update(nu, H, R + np.diag(extra) if so else R, rows, cfg.ekf_iterations)
            return
        kept = [row for row, k in zip(rows, keep, strict=True) if k]
        Rk = R[np.ix_(keep, keep)]
        for h, (nu, H, extra) in zip(self.hyps, per_hyp, strict=True):
            Rh = Rk + np.diag(extra[keep]) if so else Rk
            h.update(nu[keep], H[keep], Rh, kept, cfg.ekf_iterations)

    def _update_one(self, row: Row, report: StepReport) -> None:
        """:meth:`update_all` for a single row (most epochs) on scalars: the same gate and update, the same
        operations in the same order, without the per-row arrays."""
        cfg = self.cfg
        r_diag = cfg.sigma_delta_m**2 + cfg.sigma_v_m**2  # R = noise_cov([group]) = [[r_diag]]
        so = cfg.second_order
        rows = [row]
        per_hyp = []
        outlier_everywhere = True
        for h in self.hyps:
            nu0, extra0, hv = h.innovation(row, so)
            s_diag = float(((hv @ h.P) * hv).sum()) + r_diag + extra0
            outlier_everywhere &= nu0 * nu0 > self.gate * s_diag
            per_hyp.append((nu0, hv, extra0))
        if row.block == "i":
            if outlier_everywhere:
                report.rejected_current += 1
            else:
                report.used_current += 1
                report.kept_current.append(row)
        elif outlier_everywhere:
            report.rejected_buffered += 1
        if outlier_everywhere:
            report.rejected_keys.append(f"{row.stamp_ns}:{row.key}")
            return
        for h, (nu0, hv, extra0) in zip(self.hyps, per_hyp, strict=True):
            r = r_diag + extra0 if so else r_diag
            if cfg.ekf_iterations > 1:
                h.update(np.array([nu0]), hv[None, :], np.array([[r]]), rows, cfg.ekf_iterations)
            else:
                h._update_scalar(nu0, hv, r, rows)

    # ---- ratio, decision (6) and merge -----------------------------------------------------------------------
    def log_ratio(self) -> float | None:
        """ln delta p^{1/2} = 1/2 (ln B2 - ln B1) + 1/2 (A2 - A1); None unless two hypotheses are alive."""
        if len(self.hyps) != 2:
            return None
        h1, h2 = self.hyps
        return 0.5 * (h2.lnB - h1.lnB) + 0.5 * (h2.A - h1.A)

    def probabilities(self) -> dict[int, float]:
        lr = self.log_ratio()
        if lr is None:
            return {h.hyp_id: 1.0 for h in self.hyps}
        p1 = 1.0 / (1.0 + math.exp(-lr)) if lr > -700 else 0.0
        return {self.hyps[0].hyp_id: p1, self.hyps[1].hyp_id: 1.0 - p1}

    def decide(self) -> Decision | None:
        """Rule (6); otherwise merge when the two position estimates are closer than r."""
        lr = self.log_ratio()
        if lr is None:
            return None
        thr = self.cfg.ln_threshold
        if self.cfg.decision_statistic == "exact":
            d = self._decide_exact(lr)
            if d is not None:
                return d
        elif lr >= thr or lr <= -thr:
            keep = self.hyps[0] if lr >= thr else self.hyps[1]
            self.hyps = [keep]
            self.decided = keep.hyp_id
            return Decision("decision", keep.hyp_id, lr)
        (x1, _), (x2, _) = self.hyps[0].current(), self.hyps[1].current()
        if (x1[IX] - x2[IX]) ** 2 + (x1[IY] - x2[IY]) ** 2 < self.cfg.r_merge_m**2:
            self.hyps = [merge(self.hyps[0], self.hyps[1], lr)]
            self.merged = True
            self.exact = None
            return Decision("merge", None, lr)
        return None

    def _decide_exact(self, ekf_lr: float) -> Decision | None:
        """Honest preset: rule (6) on the exact evidence (``decision.ExactDecision``), evaluated when the EKF's
        ratio is near the threshold. Without a usable record (rows that are not ranges) no decision is made."""
        ex = self.exact
        if ex is None or not ex.due(ekf_lr):
            return None
        check = ex.check((start_of(self.hyps[0].X), start_of(self.hyps[1].X)), ekf_lr)
        self.log_ratio_at_decision = ekf_lr
        if check is None or check.accepted is None:
            return None
        keep = self.hyps[0] if check.accepted == 1 else self.hyps[1]
        self.hyps = [keep]
        self.decided = keep.hyp_id
        self.exact = None
        return Decision("decision", keep.hyp_id, check.log_ratio, check)


def merge(h1: HypothesisFilter, h2: HypothesisFilter, log_ratio: float) -> HypothesisFilter:
    """[R] Moment matching with weights p1 = dp/(1+dp), p2 = 1/(1+dp) of the full (augmented) state."""
    p1 = 1.0 / (1.0 + math.exp(-log_ratio))
    p2 = 1.0 - p1
    X = p1 * h1.X + p2 * h2.X
    d1, d2 = h1.X - X, h2.X - X
    P = p1 * (h1.P + np.outer(d1, d1)) + p2 * (h2.P + np.outer(d2, d2))
    out = HypothesisFilter(1, X, symmetrize(P))
    out.n_rows, out.crc, out.row_log = h1.n_rows, h1.crc, deque(h1.row_log, maxlen=ROW_LOG_MAX)
    return out
