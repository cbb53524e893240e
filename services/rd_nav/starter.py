"""Start without a start position (digest §4.5 [E]): K consistent snapshot fixes start the filter.

Each complete cycle (M >= 2) before the filter runs gives a snapshot fix: the multi-start Gauss-Newton solutions
of d = h(p) weighted by R_0^-1 (R_0 = c^2 [sigma_t^2 (I + 1 1^T) + sigma_f^2 I] + (sigma_c / c)^2 s s^T, the
arrival-time and sound-speed terms only), the one nearest the centroid of the beacons (inside the triangle the
solution is unique, §4.5), with P_CRLB = (H^T R^-1 H)^-1 at it (the full R of :mod:`.measurement`). When the last K
agree (carried to the newest epoch by DR, no distance check: there is no estimate yet) the filter starts as
N(X_snap, 4 P_CRLB + 0.25 I) (:class:`~services.rd_nav.initiation.Reinitialiser`).
"""

from __future__ import annotations

import numpy as np

from .config import RdNavConfig
from .cycle import CycleData
from .dr import DeadReckoner, DrPoint
from .geometry import crlb, jacobian_d, measurement_cov, multi_start_solutions
from .initiation import Proposal, Reinitialiser, Snapshot
from .measurement import MeasurementModel


class SnapshotStarter:
    """Collects the snapshot fixes of the cycles before the start and proposes the start."""

    def __init__(self, cfg: RdNavConfig, dr: DeadReckoner, model: MeasurementModel) -> None:
        self.cfg = cfg
        self.dr = dr
        self.model = model
        self.reinit = Reinitialiser(
            cfg.reinit_k, cfg.reinit_consistency_m, np.inf, cfg.reinit_crlb_scale, cfg.reinit_extra_var_m2
        )

    def clear(self) -> None:
        self.reinit.clear()

    def offer(self, cd: CycleData) -> tuple[Proposal, DrPoint] | None:
        """Record the cycle's snapshot fix; the start (and the DR state at t1) if the last K agree, else None."""
        cfg = self.cfg
        if not cfg.init_from_snapshots or cd.d.size < 2:
            return None
        zj = cd.zj
        R0 = measurement_cov(cd.s, cd.c, cfg.sigma_t_s, cfg.sigma_f_s, cd.sigma_c)
        W = np.linalg.inv(R0)
        sols = multi_start_solutions(cd.d, cd.leader, cd.followers, cd.delta, cd.depth, zj, W)
        if sols.shape[0] == 0:
            self.reinit.record(None)
            return None
        cen = np.vstack([cd.leader[None, :2], cd.followers[:, :2]]).mean(axis=0)
        p = sols[int(np.argmin(np.hypot(*(sols - cen[None, :]).T)))]
        H = jacobian_d(p.reshape(1, 2), cd.leader, cd.followers, cd.delta, cd.depth, zj)[0]
        try:
            P = crlb(H, self.model.cov(cd, p))
        except np.linalg.LinAlgError:
            self.reinit.record(None)
            return None
        b = self.dr.at(cd.t1)
        self.reinit.record(Snapshot(p=p, P_crlb=P, dr_xy=np.array([b.x_m, b.y_m])))
        prop = self.reinit.propose(None)
        return None if prop is None else (prop, b)
