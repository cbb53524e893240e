"""The EKF in shadow of the particle filter (digest §4.5 [E]): the same cycle, its own gate.

The EKF (:mod:`.ekf`, state z = (x, y, b, dphi, k)) is updated with the same d, with R evaluated at its own
position estimate, and with the motion compensation corrected by its own DR error estimate (dh/de = -H_j G_j).
Its gate is chi2_{M, gate_probability} from the same update on as the particle filter's: while the PF converges
ungated from a start or a re-seed, so does the EKF.
"""

from __future__ import annotations

from .config import RdNavConfig
from .cycle import CycleOutcome
from .ekf import EkfShadow
from .gate import Prior
from .measurement import MeasurementModel


class ShadowUpdater:
    """Runs the EKF shadow on each cycle the PF examined."""

    def __init__(self, cfg: RdNavConfig, ekf: EkfShadow, model: MeasurementModel, gates: dict[int, float]) -> None:
        self.cfg = cfg
        self.ekf = ekf
        self.model = model
        self.gates = gates

    @property
    def active(self) -> bool:
        return self.cfg.ekf_shadow and self.ekf.initialised

    def update(self, prior: Prior, updates_since_seed: int, out: CycleOutcome) -> None:
        """Update the EKF with the cycle; its (cycle status, NIS, residuals) go to ``out.ekf``."""
        if not self.active:
            return
        cfg, cd = self.cfg, prior.cd
        M = cd.d.size
        converging = updates_since_seed <= cfg.gate_after_updates and "UNGATED" in out.flags
        res = self.ekf.update(
            cd.d,
            self.model.cov(cd, self.ekf.x),
            cd.leader,
            cd.followers,
            prior.delta_for_update,
            cd.depth,
            cd.zj,
            self.gates[min(M, 16)] if cfg.gating and not converging else None,
            prior.G,
        )
        out.ekf = ("USED" if res.accepted else "REJECTED", res.nis, res.residual_m.tolist())

    def rejected(self, out: CycleOutcome) -> None:
        """A cycle rejected before the filters (CycleData.reject): the EKF reports it as rejected too."""
        if self.active:
            out.ekf = ("REJECTED", None, [])
