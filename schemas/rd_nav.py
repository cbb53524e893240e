"""AUV-group range-difference LBL navigation (digest 002): cycles, fixes and coordinator messages.

Frame: the base-station local NED frame (x north, y east, z down, metres). Receiver-clock times
(``*_local_s``) are on the producing vehicle's own monotonic clock; ``header.stamp_ns`` is the data
clock on which the vehicle's navigation sensors are stamped (architecture rule 2).
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, model_validator

from .base import Message, StrictModel, Vec2, Vec3
from .estimate import HORIZONTAL, GaussianEstimate, block_field, check_blocks

#: navigation status words of a fix (digest §7.2 ``NavFix.status``)
NavStatus = Literal["INIT", "TRACKING", "DR_ONLY", "DEGRADED_GEOMETRY", "REJECTED", "REINIT", "LOST"]
#: what happened to the cycle a fix reports on
CycleStatus = Literal["USED", "PARTIAL", "REJECTED", "NONE"]


class FollowerObs(StrictModel):
    """One follower's reply in an RD-LBL cycle, as seen by the moving AUV (digest §7.2)."""

    follower_id: str = Field(min_length=1, max_length=64)
    pos_ned_m: Vec3 = Field(description="follower transducer position (node table), NED, m")
    t_rx_local_s: float = Field(ge=0.0, description="arrival epoch on the receiver clock, s")
    dT_s: float = Field(description="t_rx - t1 on the receiver clock, s")  # noqa: N815 (digest symbol)
    tau_s: float = Field(ge=0.0, le=60.0, description="reply delay used (reported or assigned), s")
    r1j_m: float = Field(ge=0.0, description="leader-follower distance from coordinates, m")
    s_m: float = Field(description="total path difference c_est*(dT - tau), m")
    d_m: float = Field(description="range difference s - r1j, m")
    delta_ne_m: Vec2 = Field(description="DR displacement of the receiver between t1 and t_rx (north, east), m")
    valid: bool = Field(description="False if dropped (validity window, ...)")
    flag: str | None = Field(default=None, max_length=64, description="why it was dropped")


class TdoaCycle(Message):
    """One assembled RD-LBL cycle of a moving AUV (digest §7.2 ``TdoaCycle``)."""

    auv_id: str = Field(min_length=1, max_length=64)
    leader_id: str = Field(min_length=1, max_length=64)
    cycle_seq: int = Field(ge=0, lt=2**16)
    assignment_epoch: int = Field(ge=0)
    t1_local_s: float = Field(ge=0.0, description="leader arrival on the receiver clock (state epoch), s")
    leader_pos_ned_m: Vec3
    followers: list[FollowerObs] = Field(default_factory=list, max_length=32)
    c_mps: float = Field(ge=1300.0, le=1800.0, description="sound speed used, m/s")
    sigma_c_mps: float = Field(ge=0.0, le=100.0, description="its one-sigma uncertainty, m/s")
    depth_m: float = Field(ge=-20.0, le=11_000.0, description="receiver depth used, m")
    status: Literal["COMPLETE", "PARTIAL", "REJECTED"]
    reject_reason: str | None = Field(default=None, max_length=64)
    flags: list[str] = Field(default_factory=list, max_length=32, description="e.g. PARTIAL, WINDOW_REJECT:auv3")


class RdNavFix(Message):
    """Position of a moving AUV from RD-LBL + DR (digest §7.2 ``NavFix``).

    ``kind='CYCLE'`` fixes are at the leader-arrival epoch t1 of a cycle; ``kind='PROPAGATED'`` fixes are
    the same estimate carried forward by DR to the latest sensor time (covariance grown by q).
    """

    schema_version: ClassVar[int] = 2

    auv_id: str = Field(min_length=1, max_length=64)
    estimator: Literal["PF", "EKF"]
    kind: Literal["CYCLE", "PROPAGATED"]
    t_local_s: float | None = Field(default=None, description="epoch on the receiver clock (t1 of the cycle), s")
    estimate: GaussianEstimate = block_field(
        HORIZONTAL, "horizontal position x (north), y (east), covariance Q_k (Eq. 7)"
    )
    depth_m: float = Field(description="z, depth from the pressure sensor (not estimated), m")
    status: NavStatus
    valid: bool = Field(description="True if the position may be used as a fix")
    cycle_status: CycleStatus = Field(description="fate of the cycle this fix reports on")
    reject_reason: str | None = Field(default=None, max_length=64)
    leader_id: str | None = Field(default=None, max_length=64)
    cycle_seq: int | None = Field(default=None, ge=0, lt=2**16)
    n_eff: float = Field(ge=0.0, description="effective particle count 1/sum(p^2) (EKF: 0)")
    n_particles: int = Field(ge=0)
    reinit_count: int = Field(ge=0, description="re-initialisations from snapshot fixes so far")
    beacons_used: list[str] = Field(default_factory=list, max_length=32)
    residuals_m: list[float] = Field(default_factory=list, max_length=32, description="d - h(x_hat), m")
    nis: float | None = Field(default=None, ge=0.0)
    drms_crlb_m: float | None = Field(default=None, ge=0.0, description="single-cycle CRLB DRMS at x_hat, m")
    cycles_since_update: int = Field(ge=0)
    flags: list[str] = Field(default_factory=list, max_length=32)

    @model_validator(mode="after")
    def _shapes(self) -> RdNavFix:
        check_blocks(self)
        return self


VehicleEvent = Literal["DOCKED", "SERVICE_DONE", "AT_BASE", "DEPARTED", "FAULT", "HEARTBEAT"]


class VehicleStatus(Message):
    """A vehicle's report to the base coordinator (digest §7.2, acoustic telemetry)."""

    auv_id: str = Field(min_length=1, max_length=64)
    event: VehicleEvent
    t_local_s: float | None = Field(default=None, description="event time on the vehicle clock, s")
    node_id: str | None = Field(default=None, max_length=64, description="node (or base dock) involved")
    position_ned_m: Vec3 | None = Field(default=None, description="current (estimated) position, m")
    planned_route_ned_m: list[Vec3] = Field(default_factory=list, max_length=256, description="waypoints, m")
    speed_mps: float | None = Field(default=None, ge=0.0, le=10.0, description="planned transit speed, m/s")


class BeaconAssignment(Message):
    """Active beacon set chosen by the coordinator (digest §4.8, §7.2)."""

    epoch: int = Field(ge=0)
    leader_id: str = Field(min_length=1, max_length=64)
    follower_ids: list[str] = Field(min_length=1, max_length=16, description="ordered; reply-slot order")
    tau_s: list[float] = Field(min_length=1, max_length=16, description="reply delay per follower, s")
    cycle_period_s: float = Field(gt=0.0, le=600.0)
    valid_from_cycle: int | None = Field(default=None, ge=0)
    positions_ned_m: list[Vec3] = Field(default_factory=list, max_length=17, description="leader, then followers")
    cost_m: float | None = Field(default=None, ge=0.0, description="selection cost J (max CRLB DRMS), m")
    reason: str = Field(default="", max_length=128)

    @model_validator(mode="after")
    def _consistent(self) -> BeaconAssignment:
        if len(self.tau_s) != len(self.follower_ids):
            raise ValueError("one tau_s per follower")
        members = [self.leader_id, *self.follower_ids]
        if len(set(members)) != len(members):
            raise ValueError("leader and followers must be distinct")
        if self.positions_ned_m and len(self.positions_ned_m) != len(members):
            raise ValueError("positions_ned_m must list the leader and every follower")
        if any(t < 0.0 for t in self.tau_s):
            raise ValueError("tau_s must be >= 0")
        return self


class DepartureGrant(Message):
    """Permission for one docked AUV to leave (digest §2.4: at least three other beacons remain)."""

    auv_id: str = Field(min_length=1, max_length=64)
    epoch: int = Field(ge=0, description="assignment epoch in force when granted")
    reason: str = Field(default="", max_length=128)


class CoordinatorReply(Message):
    """The coordinator's answer to one input on its group uplink (closed-loop simulation, ``docs/rd_nav.md``).

    One reply per input, also when the input was refused (``rejected`` names the reason) or decided nothing, so a
    simulated group waiting for the base station's decisions knows when it has them all. The decisions are the
    ``BeaconAssignment`` and ``DepartureGrant`` messages the coordinator published for that input, in order.
    ``header.stamp_ns`` is the input's stamp.
    """

    group: str = Field(min_length=1, max_length=64)
    input_key: str = Field(min_length=1, max_length=512, description="key the answered input came on")
    input_source: str = Field(default="", max_length=256, description="its header.source (e.g. player/default)")
    input_seq: int = Field(ge=0, description="its header.seq")
    rejected: str | None = Field(default=None, max_length=64, description="reason, if the input was refused")
    assignments: list[BeaconAssignment] = Field(default_factory=list, max_length=8)
    grants: list[DepartureGrant] = Field(default_factory=list, max_length=64)
    epoch: int = Field(ge=0, description="assignment epoch in force after the input (0: none yet)")
    config_digest: str = Field(default="", max_length=64, description="digest of the coordinator's configuration")
