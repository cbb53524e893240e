"""The gate of one cycle (digest §4.4 step 8, §4.6): innovation at the estimate, geometry check, NIS gate.

Prior (:class:`Prior`): the cloud's moments before the update, x_hat and P_hat (Eqs. 6-7); with the DR error
states in the filter also the joint mean z_mean = (x_hat, m_e) and covariance C of position and DR errors, and the
cycle's motion compensation corrected by the mean errors, delta_j <- delta_j - G_j m_e.

Innovation (:class:`Innovation`), at x_hat with R from :mod:`.measurement`:

    e = d - h(x_hat),   H = dh/dx (rows (u_j - u_1)_xy),   S = H_z C H_z^T + R  (H_z = [H, -H_j G_j])
                                                       or  S = H P_hat H^T + R  (no DR error states)
    NIS = e^T S^-1 e,   DRMS_CRLB = sqrt(tr (H^T R^-1 H)^-1)   (M >= 2)

DEGRADED_GEOMETRY if DRMS_CRLB > ``degraded_drms_m`` or cond(H) > ``degraded_cond``.

Decision (:meth:`CycleGate.decide`): a non-finite NIS rejects the cycle (NON_FINITE_INNOVATION); for the first
``gate_after_updates`` updates after a start or re-seed the cycle passes ungated (the cloud is no judge yet);
otherwise NIS > chi2_{M, gate_probability} rejects it (NIS_GATE) unless one late arrival explains it
(:mod:`.rescue`): the cycle is then used without that arrival (``OUTLIER:<id>``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from shared.filters.kalman import innovation_covariance

from .config import RdNavConfig
from .cycle import CycleData, CycleOutcome
from .geometry import F64, crlb, error_jacobian, follower_units, jacobian_d, predict_d
from .measurement import MeasurementModel
from .pf import ParticleFilter
from .rescue import LateArrivalRescue


def condition_number(H: F64) -> float:
    """2-norm condition number of an M x 2 matrix from the eigenvalues of H^T H (closed form)."""
    a, b, c = float(H[:, 0] @ H[:, 0]), float(H[:, 0] @ H[:, 1]), float(H[:, 1] @ H[:, 1])
    mid, rad = 0.5 * (a + c), math.hypot(0.5 * (a - c), b)
    lo = mid - rad
    return math.sqrt((mid + rad) / lo) if lo > 0.0 else math.inf


@dataclass(frozen=True)
class Prior:
    """The cloud's moments before the cycle's update, and the cycle as the filters see it."""

    x_hat: F64  # (2,) Eq. (6), m
    P_hat: F64  # (2, 2) Eq. (7), m^2
    cd: CycleData  # motion compensation corrected by the mean DR errors (with G)
    raw_delta: F64  # (M, 2) delta_j as measured
    G: F64 | None = None  # (M, 2, 3) DR error states -> delta_j (process_model dr_errors), else None
    z_mean: F64 | None = None  # (5,) joint mean of position and DR errors
    C_joint: F64 | None = None  # (5, 5) their covariance

    @staticmethod
    def of(pf: ParticleFilter, cd: CycleData, error_states: bool) -> Prior:
        """The prior of ``pf`` for ``cd``; ``error_states``: the DR error states compensate the motion."""
        x_hat, P_hat = pf.estimate()
        if not (error_states and cd.d.size > 0):
            return Prior(x_hat, P_hat, cd, cd.delta)
        z_mean, C_joint = pf.joint_estimate()
        comp = replace(cd, delta=cd.delta - np.einsum("mij,j->mi", cd.G, z_mean[2:]))
        return Prior(x_hat, P_hat, comp, cd.delta, cd.G, z_mean, C_joint)

    @property
    def delta_for_update(self) -> F64:
        """delta_j for an update that corrects it itself with G (the PF per particle, the EKF with its estimate):
        as measured; without G the cycle's."""
        return self.raw_delta if self.G is not None else self.cd.delta


@dataclass(frozen=True)
class Innovation:
    """The cycle linearised at x_hat."""

    R: F64  # (M, M)
    e: F64  # (M,)
    H: F64  # (M, 2)
    He: F64 | None  # (M, 3) dh/de of the DR error states (geometry.error_jacobian), else None
    Hz: F64 | None  # (M, 5) [H, He], else None
    S: F64  # (M, M)
    nis: float  # all M arrivals

    def gaussian(self, prior: Prior) -> tuple[F64, F64, F64, F64, F64]:
        """(mean, covariance, Jacobian, e, S) of the linear-Gaussian view of this update (joint if possible)."""
        if self.Hz is not None and prior.C_joint is not None and prior.z_mean is not None:
            return prior.z_mean, prior.C_joint, self.Hz, self.e, self.S
        return prior.x_hat, prior.P_hat, self.H, self.e, self.S


class CycleGate:
    """Linearise a cycle at the estimate and decide whether (and without which arrival) it is used."""

    def __init__(self, cfg: RdNavConfig, model: MeasurementModel, gates: dict[int, float]) -> None:
        self.cfg = cfg
        self.model = model
        self.gates = gates  # chi2_{M, gate_probability}

    def innovate(self, prior: Prior) -> Innovation:
        """R, e, H, S and NIS at x_hat (module docstring)."""
        cd, x_hat = prior.cd, prior.x_hat
        R = self.model.cov(cd, x_hat)
        xr = x_hat.reshape(1, 2)
        zj = cd.zj
        e = cd.d - predict_d(xr, cd.leader, cd.followers, cd.delta, cd.depth, zj)[0]
        H = jacobian_d(xr, cd.leader, cd.followers, cd.delta, cd.depth, zj)[0]
        He: F64 | None = None
        Hz: F64 | None = None
        if prior.G is not None and prior.C_joint is not None:  # h also depends on the DR errors through delta_j
            He = error_jacobian(follower_units(x_hat, zj, cd.delta, cd.followers), prior.G)
            Hz = np.hstack([H, He])
            S = innovation_covariance(prior.C_joint, Hz, R)
        else:
            S = innovation_covariance(prior.P_hat, H, R)
        return Innovation(R, e, H, He, Hz, S, float(e @ np.linalg.solve(S, e)))

    def check_geometry(self, inn: Innovation, out: CycleOutcome) -> None:
        """DRMS of the single-cycle CRLB; DEGRADED_GEOMETRY if it or cond(H) is too large (M >= 2)."""
        if inn.e.size < 2:
            return
        try:
            out.drms_crlb_m = math.sqrt(max(float(np.trace(crlb(inn.H, inn.R))), 0.0))
            if out.drms_crlb_m > self.cfg.degraded_drms_m or condition_number(inn.H) > self.cfg.degraded_cond:
                out.flags.append("DEGRADED_GEOMETRY")
        except np.linalg.LinAlgError:
            out.flags.append("DEGRADED_GEOMETRY")

    def decide(
        self, inn: Innovation, ids: list[str], updates_since_seed: int, rescue: LateArrivalRescue, out: CycleOutcome
    ) -> None:
        """Gate the cycle (module docstring): sets ``out.reject``, or the dropped arrival and its transform."""
        cfg = self.cfg
        M = inn.e.size
        out.nis, out.residuals_m = inn.nis, inn.e.tolist()
        if not math.isfinite(inn.nis):
            out.reject = "NON_FINITE_INNOVATION"
        elif cfg.gating and updates_since_seed < cfg.gate_after_updates:
            out.flags.append("UNGATED")  # converging from the start disc or a re-seed: the cloud is no judge yet
        elif cfg.gating:
            gated = inn.nis > self.gates[min(M, 16)]
            try_rescue = cfg.drop_single_outlier and M >= 2 and (gated or not cfg.outlier_only_if_gated)
            late = rescue.explain(inn.e, inn.S, ids) if try_rescue else None
            if late is not None:
                out.dropped, out.T, out.nis = late.arrival_id, late.T, late.nis_rest
                out.flags.append(f"OUTLIER:{late.arrival_id}")
            elif gated:
                out.reject = "NIS_GATE"
