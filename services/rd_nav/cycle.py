"""What one closed cycle holds on its way through the filter step (digest §4.2, §4.4).

:class:`CycleData` is the cycle's numbers as measured (built by the core from an assembled
:class:`~services.rd_nav.assembler.OpenCycle`); :class:`CycleOutcome` is the record the components of the filter
step (:mod:`.gate`, :mod:`.rescue`, :mod:`.pf_update`, :mod:`.reinit_policy`, :mod:`.shadow`) fill in, one part
each, and :mod:`.fixes` reads.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from schemas.rd_nav import TdoaCycle

from .assembler import OpenCycle
from .geometry import F64


@dataclass
class CycleData:
    """The numbers of one closed cycle, ready for the filters."""

    oc: OpenCycle
    t1: float
    t1_stamp_ns: int
    ids: list[str]
    leader: F64
    followers: F64  # (M, 3) valid followers
    d: F64  # (M,)
    s: F64  # (M,)
    delta: F64  # (M, 2)
    G: F64  # (M, 2, 3) how the DR error states move delta_j (drift.py), zeros without motion compensation
    iv: F64  # (M,) variance of the trapezoid's error over each delta_j (velocity changes), m^2
    dt: F64  # (M,) receiver-clock time from the leader arrival, s
    tau: F64
    pos_sigma: F64  # (M+1,) leader first
    c: float
    sigma_c: float
    depth: float
    msg: TdoaCycle
    reject: str | None

    @property
    def zj(self) -> F64:
        """(M,) receiver depth at each follower's arrival: the depth of the cycle, m."""
        return np.full(self.d.size, self.depth)


@dataclass
class CycleOutcome:
    """What the filter step made of one cycle (filled in step by step)."""

    reject: str | None  # the cycle's reject reason (CycleData.reject first, then the filter's)
    flags: list[str]
    event: str = ""  # "USED", "REINIT" or "" (not used)
    nis: float | None = None  # NIS of what was used (the reduced one after a rescue)
    residuals_m: list[float] = field(default_factory=list)  # e at x_hat, all M
    drms_crlb_m: float | None = None
    dropped: str | None = None  # the late arrival left out (rescue)
    T: F64 | None = None  # its transform, T g = 0
    ekf: tuple[str, float | None, list[float]] | None = None  # EKF shadow (cycle status, NIS, residuals)

    @property
    def rescued(self) -> bool:
        return self.T is not None
