"""The two-filter sequential alternative the paper compares against (digest 000, section 2.6: "KF + KF").

A backward-time filter processes the buffered epochs and estimates the launch state X_0 from them alone
(diffuse prior on X_0); a forward filter processes the current epochs and carries a fixed copy of X_0 next to
X_i (the same 11-state layout as the augmented filter, with the copy held constant). Their results are fused by
a fictitious measurement: the backward estimate of X_0, with its covariance, applied to the forward filter's copy.
Run sequentially, one epoch = Delta N backward steps, one forward step and one fusion. Both filters use the same
update code (with the common gate) as the single-filter scheme, so the time comparison is of the schemes.
It exists for the paper's time comparison (bench) and to check that it reaches the single-filter estimate
(tests); it handles one hypothesis.
"""

from __future__ import annotations

import numpy as np

from shared.filters import kalman

from .config import LblNavConfig
from .filter import BufferedEpoch, HypothesisBank, HypothesisFilter, StepReport
from .models import AUG, F64, DrInterval, MotionModel, Row

#: diffuse prior of the backward filter's X_0 (m^2, m^2, (m/s)^2, rad^2, (m/s)^2, (m/s)^2)
DIFFUSE = (1e10, 1e10, 1e6, 1e2, 1e4, 1e4)
#: where the components of X_0 = (x, y, dc, dK, dU_N, dU_E) sit in the forward filter's 11-state vector
COPY_OF_X0 = [0, 1, AUG + 2, 2, 3, 4]


class TwoFilterScheme:
    """KF + KF: backward filter on the buffer, forward filter on current data, fictitious-measurement fusion."""

    def __init__(self, cfg: LblNavConfig, X0: F64, P0: F64, buffer: list[BufferedEpoch], launch_dr: DrInterval) -> None:
        self.cfg = cfg
        self.motion = MotionModel(cfg)
        self.backward = HypothesisBank(cfg, self.motion, [HypothesisFilter(0, X0, np.diag(DIFFUSE))], buffer, launch_dr)
        fwd = HypothesisFilter(1, X0, P0)
        fwd.augment()  # [copy of X_0 (x, y, dK, dU), X_i]; the copy is never predicted
        self.forward = HypothesisBank(cfg, self.motion, [fwd], [], None)
        self._I5 = np.eye(5)
        self._z5 = np.zeros(5)
        self._Z5 = np.zeros((5, 5))
        self.X_fused, self.P_fused = np.array(X0, dtype=np.float64), np.array(P0, dtype=np.float64)

    @property
    def catching_up(self) -> bool:
        return self.backward.catching_up

    def _forward_step(self, dr: DrInterval, rows: list[Row]) -> None:
        h = self.forward.hyps[0]
        Phi, b, Q = self.motion.forward(dr)
        if h.augmented:
            h.predict_joint(self._I5, self._z5, self._Z5, Phi, b, Q)
        else:
            h.predict_forward(Phi, b, Q)
        self.forward.update_all(rows, StepReport())

    def _fuse(self) -> None:
        """Fictitious measurement z = X_0^B (covariance of the backward X_0) of the forward copy of X_0."""
        zb, Rb = self.backward.hyps[0].current()
        h = self.forward.hyps[0]
        H = np.zeros((6, 11))
        H[np.arange(6), COPY_OF_X0] = 1.0
        PHt = h.P @ H.T
        S = H @ PHt + Rb
        K = PHt @ np.linalg.inv(S)
        X = h.X + K @ (zb - h.X[COPY_OF_X0])
        self.X_fused, self.P_fused = X[AUG:], kalman.joseph(h.P, K, H, Rb)[AUG:, AUG:]

    def launch_steps(self) -> None:
        self.backward.launch_steps()
        if self.backward.N:
            self._fuse()

    def epoch_step(self, dr: DrInterval, rows: list[Row]) -> None:
        """One epoch: Delta N backward steps (while buffered epochs remain), one forward step, the fusion."""
        h = self.forward.hyps[0]
        if not h.augmented:  # buffered data already fused: a plain 6-state EKF
            self._forward_step(dr, rows)
            self.X_fused, self.P_fused = h.X.copy(), h.P.copy()
            return
        self.backward.process_buffered(self.cfg.dN)
        self._forward_step(dr, rows)
        self._fuse()
        if not self.backward.catching_up:
            # buffered data exhausted: continue from the fused state with the 6-state forward filter
            self.forward.hyps[0] = HypothesisFilter(1, self.X_fused, self.P_fused)
