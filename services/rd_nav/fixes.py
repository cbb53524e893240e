"""RdNavFix from what a filter step produced (digest §7.3 S6): one small record in, one message out.

The reported covariance is sym(P) + 1e-9 I m^2 (a collapsed cloud still reports a positive-definite P); the
depth is the receiver's last depth (0 before any); ``valid`` means the filter is initialised and not LOST.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from schemas import Header
from schemas.rd_nav import RdNavFix
from shared.estimates import HORIZONTAL, gaussian
from shared.filters.covariance import symmetrize

from .config import RdNavConfig
from .cycle import CycleData
from .geometry import F64


@dataclass(frozen=True)
class FilterState:
    """What every fix reports of the filter's state at its time."""

    initialised: bool
    depth_m: float | None
    reinit_count: int
    cycles_since_update: int


@dataclass(frozen=True)
class FixContent:
    """One fix: estimator, kind, epoch, estimate and what the cycle (if any) did."""

    estimator: str  # "PF" or "EKF"
    kind: str  # "CYCLE" (epoch t1) or "PROPAGATED"
    stamp_ns: int
    x: F64  # (2,) north, east, m
    P: F64  # (2, 2) m^2
    status: str
    n_eff: float
    t_local_s: float | None = None  # leader arrival on the receiver clock (CYCLE)
    cycle_status: str = "NONE"
    reject: str | None = None
    cd: CycleData | None = None
    beacons: list[str] = field(default_factory=list)  # arrivals used (leader first), if the cycle was used
    residuals_m: list[float] = field(default_factory=list)
    nis: float | None = None
    drms_crlb_m: float | None = None
    flags: list[str] = field(default_factory=list)


class FixBuilder:
    """Builds the RdNavFix messages of one AUV."""

    def __init__(self, cfg: RdNavConfig) -> None:
        self.cfg = cfg

    def build(self, f: FixContent, state: FilterState) -> RdNavFix:
        cfg, cd, nis = self.cfg, f.cd, f.nis
        P = symmetrize(f.P) + 1e-9 * np.eye(2)  # a collapsed cloud still reports a positive-definite P
        return RdNavFix(
            header=Header(stamp_ns=f.stamp_ns, frame_id=cfg.frame_id),
            auv_id=cfg.auv_id,
            estimator=f.estimator,  # type: ignore[arg-type]
            kind=f.kind,  # type: ignore[arg-type]
            t_local_s=f.t_local_s,
            estimate=gaussian(cfg.frame_id, HORIZONTAL, [float(f.x[0]), float(f.x[1])], P.tolist()),
            depth_m=float(state.depth_m if state.depth_m is not None else 0.0),
            status=f.status,  # type: ignore[arg-type]
            valid=state.initialised and f.status != "LOST",
            cycle_status=f.cycle_status,  # type: ignore[arg-type]
            reject_reason=f.reject,
            leader_id=cd.oc.leader_id if cd is not None else None,
            cycle_seq=cd.oc.cycle_seq if cd is not None else None,
            n_eff=float(f.n_eff),
            n_particles=cfg.n_particles if f.estimator == "PF" else 0,
            reinit_count=state.reinit_count,
            beacons_used=list(f.beacons) if f.cycle_status in ("USED", "PARTIAL") else [],
            residuals_m=[float(v) for v in f.residuals_m],
            nis=nis if nis is None or math.isfinite(nis) else None,
            drms_crlb_m=f.drms_crlb_m,
            cycles_since_update=state.cycles_since_update,
            flags=sorted(set(f.flags))[:32],
        )
