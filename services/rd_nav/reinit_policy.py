"""Loss-of-lock policy (digest §4.4 step 8, §4.5): when a cycle counts towards losing lock, and when to re-seed.

A cycle counts if the filter could not use it whole: gated out (NIS_GATE), no overlap (NO_OVERLAP), or used
without one late arrival (a rescue). Each such cycle (M >= 2) gives a snapshot Gauss-Newton fix X_snap, the
solution nearest x_hat, with P_CRLB = (H^T R^-1 H)^-1 at it; after K of them in a row whose fixes, carried to the
newest epoch by DR, agree within 5 m (plus the DR drift bound over their span) and lie within 1 km of x_hat, the
cloud is re-seeded as N(X_snap, 4 P_CRLB + 0.25 I) (:class:`~services.rd_nav.initiation.Reinitialiser`). If the
same beacon's late arrival (>= ``reinit_late_arrival_min_m``) explains every one of those cycles at x_hat to
measurement precision (S = R, chi2_{0.95}), ``reinit_k_same_outlier`` cycles are required instead.

A cycle used whole ends the run; a partial (M = 1) one only with ``reinit_strict_chain`` (inside the gate it
does not prove lock).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from shared.filters.covariance import is_positive_definite

from .config import RdNavConfig
from .cycle import CycleData, CycleOutcome
from .dr import DeadReckoner
from .gate import Innovation
from .geometry import F64, crlb, gauss_newton, jacobian_d, multi_start_solutions
from .initiation import Proposal, Reinitialiser, Snapshot
from .rescue import one_late_arrival


def snapshot_fix(cfg: RdNavConfig, dr: DeadReckoner, cd: CycleData, x_hat: F64, R: F64) -> Snapshot | None:
    """Snapshot Gauss-Newton fix of one cycle (§4.5), the solution nearest x_hat, with P_CRLB at it."""
    zj = cd.zj
    W = np.linalg.inv(R)
    gn: dict[str, Any] = {"max_iter": cfg.gn_max_iter, "step_limit_m": cfg.gn_step_limit_m, "tol_m": cfg.gn_tol_m}
    r = gauss_newton(cd.d, x_hat.reshape(1, 2), cd.leader, cd.followers, cd.delta, cd.depth, zj, W, **gn)
    tol = 5.0 * math.sqrt(float(np.trace(R)))
    if r.converged[0] and r.residual_m[0] < tol:
        p = r.p[0]
    else:
        sols = multi_start_solutions(
            cd.d, cd.leader, cd.followers, cd.delta, cd.depth, zj, W, x_hat.reshape(1, 2), tol, **gn
        )
        if sols.shape[0] == 0:
            return None
        p = sols[int(np.argmin(np.hypot(*(sols - x_hat[None, :]).T)))]
    try:
        H = jacobian_d(p.reshape(1, 2), cd.leader, cd.followers, cd.delta, cd.depth, zj)[0]
        P = crlb(H, R)
    except np.linalg.LinAlgError:
        return None
    if not is_positive_definite(P):
        return None
    b = dr.at(cd.t1)
    return Snapshot(p=p.copy(), P_crlb=P, dr_xy=np.array([b.x_m, b.y_m]), t_s=cd.t1)


class LossOfLock:
    """Counts the cycles the filter could not use whole and proposes a re-seed from their snapshot fixes."""

    def __init__(self, cfg: RdNavConfig, dr: DeadReckoner, gate_1: float, gates_typical: dict[int, float]) -> None:
        self.cfg = cfg
        self.dr = dr
        self.gate_1 = gate_1  # chi2_{1, gate_probability}
        self.gates_typical = gates_typical  # chi2_{m, 0.95}
        self.reinit = Reinitialiser(
            cfg.reinit_k,
            cfg.reinit_consistency_m,
            cfg.reinit_max_distance_m,
            cfg.reinit_crlb_scale,
            cfg.reinit_extra_var_m2,
            cfg.reinit_k_same_outlier,
            drift_mps=cfg.reinit_drift_sigma * math.sqrt(2.0) * cfg.sigma_dr_velocity_mps,
            strict_chain=cfg.reinit_strict_chain,
        )

    def clear(self) -> None:
        self.reinit.clear()

    def on_used(self, out: CycleOutcome, M: int) -> None:
        """A used cycle: a whole one (M >= 2, or any with ``reinit_strict_chain``) ends the run."""
        if not out.rescued and (M >= 2 or self.cfg.reinit_strict_chain):
            self.reinit.clear()  # a partial (M = 1) cycle inside the gate does not prove lock

    def counts(self, out: CycleOutcome) -> bool:
        """Does this cycle count towards loss of lock?"""
        return (out.rescued or out.reject in ("NIS_GATE", "NO_OVERLAP")) and self.cfg.reinit

    def on_failed(self, cd: CycleData, inn: Innovation, x_hat: F64) -> Proposal | None:
        """Record a cycle that counts (its snapshot fix, and the late arrival explaining it at x_hat to measurement
        precision, if any); the re-seed N(X_snap, 4 P_CRLB + 0.25 I) if the last K agree, else None."""
        M = cd.d.size
        tag = None
        if M >= 2 and math.isfinite(inn.nis):
            explained = one_late_arrival(
                inn.e, inn.R, cd.ids, self.gate_1, self.gates_typical, self.cfg.reinit_late_arrival_min_m
            )
            tag = explained.arrival_id if explained is not None else None
        self.reinit.record(snapshot_fix(self.cfg, self.dr, cd, x_hat, inn.R) if M >= 2 else None, tag)
        return self.reinit.propose(x_hat)
