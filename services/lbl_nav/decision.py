"""Rule (6) on the exact evidence of the whole record: the decision of the ``honest`` preset.

The paper's rule compares the EKF's accumulated ln dp with +/- ln 10^4 (``preset: paper``). The honest rule keeps
that as a trigger only: when the EKF's ratio comes within ``exact_trigger_decades`` of the threshold, the record
of every range received so far (all N buffered epochs, the launch epoch, the current epochs the common gate kept)
is evaluated exactly by :mod:`.evidence` for both hypotheses, and a hypothesis is accepted only if

1. the exact ln dp is beyond the threshold, and
2. it stays beyond the threshold when the error-state priors are widened by ``robust_prior_scale`` (sigma_dK and
   sigma_dU times kappa): a robust-Bayes check.

Why the second condition. On a straight track the mirror image of the true track is itself a possible track
(ranges to beacons on the line are symmetric), so the only thing that tells the two apart is how large a heading
(and current) error each needs: the mirror of a track theta off the line needs a heading error larger by
about 2 theta. A ratio of 10^4 on such data rests on the tails of the Gaussian priors of dK and dU, and the
Monte-Carlo of the fixed-track family (``docs/lbl_nav.md``) shows wrong decisions at several per thousand where
rule (6) promises 10^-4, with the exact ratio as well as the EKF's. Evidence from geometry (turns, a second
beacon at another bearing, a track well off the line) does not depend on the prior's width and passes the
check; evidence that exists only because a 3-sigma compass error is judged less likely than a 4-sigma one does
not. The check only delays or withholds decisions; it never makes one.

The exact evaluation costs a few tens of milliseconds per hypothesis; it runs at most every
``exact_recheck_epochs`` epochs and only while the EKF ratio is near the threshold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .config import LblNavConfig
from .evidence import EvidenceEpoch, Fit, Priors, RangeObs, Record, Start, fit
from .models import AUG, IDC, IDK, IUE, IUN, IX, IY, DrInterval, RangeRow, Row


def evidence_epoch(dr: DrInterval, rows: list[Row]) -> EvidenceEpoch | None:
    """The record entry of one epoch; None if a row is not a range (the exact statistic needs Eq. (1))."""
    obs = []
    for r in rows:
        if not isinstance(r, RangeRow):
            return None
        obs.append(RangeObs(r.bx, r.by, r.bz, r.z, r.value, r.T_s / r.value if r.value > 0.0 else 0.0))
    return EvidenceEpoch(dr.dt_s, dr.ve_dt_m, dr.vn_dt_m, dr.ue_dt_m, dr.un_dt_m, dr.sigma_w_scale, tuple(obs))


@dataclass(frozen=True)
class ExactCheck:
    """One exact evaluation: ln dp^{1/2} with the configured priors and with the widened priors (nats), the
    accepted hypothesis id (None: no decision) and the number of epochs in the record."""

    log_ratio: float
    log_ratio_robust: float | None
    accepted: int | None
    epochs: int


class ExactDecision:
    """The record of one vehicle's two-hypothesis phase and rule (6) on its exact evidence."""

    def __init__(self, cfg: LblNavConfig, epochs: list[EvidenceEpoch | None]) -> None:
        self.cfg = cfg
        self.usable = all(e is not None for e in epochs)
        self.epochs: list[EvidenceEpoch] = [e for e in epochs if e is not None]
        self.pri = Priors.of(cfg)
        k = cfg.robust_prior_scale
        self.pri_robust = (
            replace(self.pri, sigma_dK_rad=self.pri.sigma_dK_rad * k, sigma_dU_mps=self.pri.sigma_dU_mps * k)
            if k != 1.0
            else None
        )
        self._last_check: int | None = None
        self._last_ekf = 0.0
        self._misses = 0
        #: the last MAP solutions (z, epochs) per (prior set, hypothesis index): warm starts
        self._warm: dict[tuple[bool, int], tuple[np.ndarray, int]] = {}
        self.last: ExactCheck | None = None
        self.evaluations = 0
        self.failures = 0

    def append(self, dr: DrInterval, rows: list[Row]) -> None:
        e = evidence_epoch(dr, rows)
        if e is None:
            self.usable = False
        else:
            self.epochs.append(e)

    def due(self, ekf_log_ratio: float) -> bool:
        """Whether to evaluate now: at launch (all buffered data at once), then while the EKF ratio is within
        ``exact_trigger_decades`` of the threshold, at most every ``exact_recheck_epochs`` epochs, the interval
        doubling after each evaluation that did not decide (up to 16 times) unless the EKF ratio has grown by
        half a decade since."""
        cfg = self.cfg
        if not self.usable:
            return False
        if self._last_check is None:
            return True
        ln10 = math.log(10)
        a = abs(ekf_log_ratio)
        if a < cfg.ln_threshold - cfg.exact_trigger_decades * ln10:
            return False
        interval = cfg.exact_recheck_epochs * 2 ** min(self._misses, 4)
        return len(self.epochs) - self._last_check >= interval or a >= abs(self._last_ekf) + 0.5 * ln10

    def check(self, starts: tuple[Start, Start], ekf_log_ratio: float = 0.0) -> ExactCheck | None:
        """Evaluate both hypotheses on the record (Gauss-Newton from their last MAP solutions, else from their
        EKF estimates); None if it fails (no decision, state untouched)."""
        self._last_check = len(self.epochs)
        self._last_ekf = ekf_log_ratio
        self.evaluations += 1
        thr = self.cfg.ln_threshold
        try:
            lr = self._log_ratio(False, starts)
            lr_r = None
            accepted: int | None = 1 if lr >= thr else 2 if lr <= -thr else None
            if accepted is not None and self.pri_robust is not None:
                lr_r = self._log_ratio(True, starts)
                if not ((lr_r >= thr and accepted == 1) or (lr_r <= -thr and accepted == 2)):
                    accepted = None
        except (np.linalg.LinAlgError, ValueError, FloatingPointError, ArithmeticError):
            self.failures += 1
            return None
        self._misses = 0 if accepted is not None else self._misses + 1
        self.last = ExactCheck(lr, lr_r, accepted, len(self.epochs))
        return self.last

    def _log_ratio(self, robust: bool, starts: tuple[Start, Start]) -> float:
        """ln p(Y | u = 1) - ln p(Y | u = 2), Laplace at each hypothesis's MAP. Gauss-Newton runs from the
        hypothesis's EKF estimate and, if there is one, from its last MAP solution carried forward; the solution
        with the lower cost is the MAP (a warm start alone once settled in a worse local optimum: a wrong decision
        of the 5 deg family, docs/lbl_nav.md)."""
        pri = self.pri_robust if robust and self.pri_robust is not None else self.pri
        rec = Record(self.epochs, pri)
        ev = []
        for u, start in enumerate(starts):
            best: Fit | None = None
            warm = self._warm.get((robust, u))
            for z0 in (None, rec.extend(*warm) if warm is not None else None):
                if z0 is None and best is not None:
                    continue
                try:
                    f: Fit = fit(rec, start, z0=z0)
                except (np.linalg.LinAlgError, ArithmeticError):
                    continue
                if f.converged and (best is None or f.cost < best.cost):
                    best = f
            if best is None:
                raise ArithmeticError("Gauss-Newton did not converge")
            self._warm[(robust, u)] = (best.z, rec.n)
            ev.append(best.log_evidence)
        lr = ev[0] - ev[1]
        if not math.isfinite(lr):
            raise ArithmeticError("exact log ratio is not finite")
        return lr


def start_of(X: np.ndarray) -> Start:
    """Gauss-Newton start from a hypothesis's current EKF state (6 states, or 11 while augmented)."""
    x = X[AUG:] if X.size == 11 else X
    return Start(float(x[IX]), float(x[IY]), float(x[IDC]), float(x[IDK]), float(x[IUN]), float(x[IUE]))
