"""Navigation sensor streams: speed log/DVL, heading and attitude, depth, current, INS, altimeters."""

from __future__ import annotations

import math

from pydantic import Field

from .base import Message

TWO_PI = 2.0 * math.pi


class SpeedLog(Message):
    """Relative (log) or bottom-track (DVL) velocity in the body frame."""

    v_forward_mps: float = Field(ge=-30.0, le=30.0, description="along the longitudinal axis, m/s")
    v_starboard_mps: float = Field(ge=-30.0, le=30.0, description="transverse, + to starboard, m/s")
    v_down_mps: float = Field(default=0.0, ge=-30.0, le=30.0, description="vertical, + down, m/s")
    avg_interval_s: float = Field(default=1.0, gt=0.0, le=60.0, description="averaging interval of the sample")
    bottom_lock: bool = Field(default=True, description="DVL bottom lock (False: water-track or invalid)")


class Heading(Message):
    """Heading, clockwise from geographic north."""

    heading_rad: float = Field(ge=-TWO_PI, le=TWO_PI, description="rad, clockwise from true north")


class Attitude(Message):
    """Heading, pitch and roll of a vehicle (rad)."""

    heading_rad: float = Field(ge=-TWO_PI, le=TWO_PI, description="clockwise from true north")
    pitch_rad: float = Field(ge=-math.pi / 2, le=math.pi / 2, description="nose up positive")
    roll_rad: float = Field(ge=-math.pi, le=math.pi, description="starboard down positive")


class Depth(Message):
    """Depth below the surface from a pressure sensor."""

    depth_m: float = Field(ge=-20.0, le=11_000.0, description="m, positive down")


class Current(Message):
    """Known (approximate) water current."""

    u_north_mps: float = Field(ge=-10.0, le=10.0)
    u_east_mps: float = Field(ge=-10.0, le=10.0)


class SoundSpeed(Message):
    """Speed of sound in water and its uncertainty."""

    c_mps: float = Field(ge=1300.0, le=1800.0, description="m/s")
    sigma_c_mps: float = Field(default=1.0, gt=0.0, le=100.0)
    model: str = Field(default="measured", max_length=64, description="e.g. measured, Mackenzie1981, default")


class InsSample(Message):
    """Indicated INS position in the map frame (x along-track map axis, z transverse) and altitude."""

    x_m: float = Field(description="indicated longitudinal map coordinate, m")
    z_m: float = Field(description="indicated transverse map coordinate, m")
    h_m: float = Field(ge=-1_000.0, le=30_000.0, description="indicated altitude on the map's datum, m")
    vx_mps: float | None = Field(default=None, ge=-1_500.0, le=1_500.0)
    vz_mps: float | None = Field(default=None, ge=-1_500.0, le=1_500.0)
    vh_mps: float | None = Field(default=None, ge=-500.0, le=500.0, description="vertical speed, + up")
    valid: bool = True


class RadioAltimeter(Message):
    """Radio-altimeter height above ground with the sensor's data-valid flag."""

    h_agl_m: float = Field(ge=0.0, le=30_000.0, description="height above ground level, m")
    valid: bool = Field(default=True, description="the altimeter's data-valid flag")


class BaroAltitude(Message):
    """Barometric altitude on the same vertical datum as the map."""

    h_baro_m: float = Field(ge=-1_000.0, le=30_000.0)
    valid: bool = True


class NavReset(Message):
    """Control: the navigation system was reset externally; estimators clear their state."""

    reason: str = Field(max_length=256)
