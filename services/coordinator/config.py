"""Parameters of the coordinator core with the digest's defaults ([P] paper, [E] engineering, [D] derived)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator


class CoordinatorConfig(BaseModel):
    """Configuration of :class:`services.coordinator.core.CoordinatorCore`."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    frame_id: str = Field(default="base_ned")
    min_beacons: int = Field(default=3, ge=2, description="stationary beacons required at all times [P]")
    n_followers: int = Field(default=2, ge=1, description="followers in the active set (M) [P]")
    allow_partial_set: bool = Field(default=True, description="leader + 1 follower when fewer beacons [E]")
    tau_slots_s: list[float] = Field(default_factory=lambda: [0.5, 3.5], description="reply slots, s [E]")
    cycle_period_s: float = Field(default=10.0, gt=0.0, description="T_c, s [E]")
    c_mps: float = Field(default=1500.0, gt=0.0, description="nominal sound speed, m/s")
    sigma_t_s: float = Field(default=0.2e-3, gt=0.0, description="arrival-time noise, for the cost in m [E]")
    cost_model: Literal["full", "arrival_time"] = Field(
        default="full",
        description="full: every (set, leader, reply order) scored by its single-cycle CRLB DRMS with the full R of "
        "§4.2/§4.6 (arrival time, follower jitter, sound speed, node survey, DR motion compensation) and only "
        "schedules that fit T_c; arrival_time: the digest's §4.8 recipe (GDOP with arrival-time noise only, leader "
        "by the shortest cycle) [E]",
    )
    sigma_f_s: float = Field(default=0.0, ge=0.0, description="follower reply jitter, s (full cost) [E]")
    sigma_c_mps: float = Field(
        default=0.3, ge=0.0, description="per-cycle sound-speed error of the receivers, m/s (full cost) [D §5.4]"
    )
    sigma_node_m: float = Field(default=0.0, ge=0.0, description="node survey error per axis, m (full cost) [E]")
    sigma_dr_velocity_mps: float = Field(
        default=0.05, ge=0.0, description="DR velocity error over a cycle's arrivals, m/s (full cost) [E]"
    )
    t_pkt_s: float = Field(default=0.4, ge=0.0, description="packet length, s (schedule check) [E]")
    guard_s: float = Field(default=0.1, ge=0.0, description="guard time, s (schedule check, §4.9) [E]")
    horizon_s: float = Field(default=900.0, ge=0.0, description="planned-route horizon H, s [E]")
    route_sample_m: float = Field(default=250.0, gt=0.0, description="spacing of route points, m [E]")
    eval_depth_m: float = Field(default=80.0, description="receiver depth of the evaluation points, m [E]")
    hysteresis: float = Field(default=0.2, ge=0.0, lt=1.0, description="switch if J improves by more [E]")
    baseline_ext_margin_m: float = Field(
        default=300.0, ge=0.0, description="exclude sets with a route point this close to a baseline extension [E]"
    )
    baseline_ext_min_beyond_m: float = Field(
        default=100.0, ge=0.0, description="... and at least this far beyond the end beacon, m [E]"
    )
    reselect_period_s: float = Field(default=60.0, gt=0.0, description="periodic re-selection, s [E]")
    beacon_timeout_s: float = Field(default=30.0, gt=0.0, description="active beacon silent -> removed (3 T_c) [E]")
    standby_timeout_s: float | None = Field(default=None, description="standby beacon silent -> removed [E]")
    base_auvs_as_beacons: bool = Field(default=True, description="AUVs parked at the base are beacons [P]")
    base_node_id: str = Field(default="base", description="base docks are '<base>/<auv_id>' or '<base>' [E]")
    grant_delay_s: float = Field(
        default=10.0, ge=0.0, description="hold a grant this long after re-assigning away from the AUV [E]"
    )
    grant_on_epoch_heard: bool = Field(default=True, description="or until a packet of the new epoch is heard [E]")
    node_table_ned_m: dict[str, tuple[float, float, float]] = Field(
        default_factory=dict, description="node_id -> surveyed (north, east, depth), m"
    )

    @model_validator(mode="after")
    def _slots(self) -> CoordinatorConfig:
        if len(self.tau_slots_s) < self.n_followers:
            raise ValueError("tau_slots_s needs one reply delay per follower")
        return self
