"""Acoustic positioning streams: LBL beacon tables and ranges, RD-LBL packets and arrivals."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from .base import Message, StrictModel, Vec3, VecComponent

#: speed of light is irrelevant here; ranges under water never exceed this
MAX_ACOUSTIC_RANGE_M = 50_000.0


class Beacon(StrictModel):
    beacon_id: str = Field(min_length=1, max_length=64)
    x_east_m: VecComponent
    y_north_m: VecComponent
    depth_m: float = Field(ge=-20.0, le=11_000.0)


class BeaconTable(Message):
    """Surveyed beacon positions in the local east/north/depth frame."""

    beacons: list[Beacon] = Field(min_length=1, max_length=256)


class BeaconRange(Message):
    """One-way travel time or slant range to a beacon (exactly one of the two)."""

    beacon_id: str = Field(min_length=1, max_length=64)
    travel_time_s: float | None = Field(default=None, gt=0.0, le=40.0, description="one-way, s")
    range_m: float | None = Field(default=None, gt=0.0, le=MAX_ACOUSTIC_RANGE_M, description="slant, m")
    quality: float | None = Field(default=None, ge=0.0, le=1.0)

    @model_validator(mode="after")
    def _exactly_one(self) -> BeaconRange:
        if (self.travel_time_s is None) == (self.range_m is None):
            raise ValueError("exactly one of travel_time_s and range_m must be given")
        return self


class NavPacket(StrictModel):
    """Payload of an RD-LBL acoustic packet (leader broadcast or follower reply)."""

    sender_id: str = Field(min_length=1, max_length=64)
    kind: Literal["LEADER", "FOLLOWER"]
    leader_id: str = Field(min_length=1, max_length=64)
    cycle_seq: int = Field(ge=0, lt=2**16)
    assignment_epoch: int = Field(ge=0, le=2**62)
    node_id: str | None = Field(default=None, max_length=64)
    pos_ned_m: Vec3 = Field(description="beacon transducer position, NED, m")
    pos_sigma_m: float = Field(ge=0.0, le=1_000.0)
    reply_delay_s: float | None = Field(default=None, ge=0.0, le=60.0, description="follower's own clock")
    state_flags: int = Field(default=0, ge=0, le=2**32 - 1)


class AcousticArrival(Message):
    """A decoded acoustic packet with its arrival time on the receiver's own clock."""

    receiver_id: str = Field(min_length=1, max_length=64)
    t_rx_local_s: float = Field(ge=0.0, description="arrival epoch on the receiver's monotonic clock, s")
    packet: NavPacket
    snr_db: float | None = None
    corr_peak: float | None = Field(default=None, ge=0.0)
