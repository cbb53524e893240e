"""Navigation sensors of ``nav_platform``: parameter models and sample generation against a trajectory.

Every sensor samples the true state at ``start_s + k / rate_hz`` and adds its error model. Each error
source is either a fixed value (``bias_*``) or a standard deviation (``*sigma*``) drawn per run from the
sensor's own random stream, so adding or removing a sensor does not change the noise of the others.
Errors are ``measured - true``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, Field

from schemas import Depth, Heading, InsSample, Message, SpeedLog
from shared import keys
from shared.filters import gauss_markov

from .base import NS_PER_S, Event, ScenarioContext, SimParams, sample_stamps_ns
from .columns import ColumnStream
from .error_models import random_walk, white
from .trajectory import TWO_PI, Trajectory


def _chunk(v: str) -> str:
    return keys.chunk(v)


KeyChunk = Annotated[str, AfterValidator(_chunk)]


def _vec3(v: list[float]) -> list[float]:
    if len(v) != 3:
        raise ValueError(f"expected [forward, starboard, down], 3 components, got {len(v)}")
    return v


class SensorParams(SimParams):
    """What every sensor has: an id (last key chunk), a rate and a start time."""

    id: KeyChunk = Field(description="sensor id, the last chunk of its key")
    rate_hz: float = Field(gt=0.0, le=1000.0, description="sample rate, Hz")
    start_s: float = Field(default=0.0, ge=0.0, description="time of the first sample, s")


class SpeedLogParams(SensorParams):
    """Speed log (water-relative, ``speed_log``) or DVL (bottom-track, ``dvl``).

    Velocity in the vehicle's level frame (forward and starboard horizontal, down vertical), i.e. after
    attitude compensation. Error per sample and axis: constant bias + white noise.
    """

    type: Literal["dvl", "speed_log"]
    sigma_mps: float = Field(default=0.0, ge=0.0, le=10.0, description="white noise per sample and axis, m/s")
    bias_mps: Annotated[list[float], AfterValidator(_vec3)] = Field(
        default_factory=lambda: [0.0, 0.0, 0.0], description="[forward, starboard, down] constant bias, m/s"
    )


class HeadingParams(SensorParams):
    """Heading (compass/gyro): constant bias + first-order Gauss-Markov + white noise."""

    type: Literal["heading"]
    bias_deg: float = Field(default=0.0, ge=-180.0, le=180.0, description="constant bias, deg")
    gm_sigma_deg: float = Field(default=0.0, ge=0.0, le=90.0, description="Gauss-Markov stationary SD, deg")
    gm_tau_s: float = Field(default=300.0, gt=0.0, le=1e7, description="Gauss-Markov correlation time, s")
    white_sigma_deg: float = Field(default=0.0, ge=0.0, le=90.0, description="white noise per sample, deg")


class DepthParams(SensorParams):
    """Pressure depth sensor (AUV only): constant bias + white noise. Depth = -up."""

    type: Literal["depth"]
    sigma_m: float = Field(default=0.0, ge=0.0, le=100.0, description="white noise per sample, m")
    bias_m: float = Field(default=0.0, ge=-100.0, le=100.0, description="constant bias, m")


class InsParams(SensorParams):
    """INS indicated position with a random-walk horizontal drift.

    ``x_m`` = north, ``z_m`` = east (the x-forward, y-up, z-east map convention), ``h_m`` = up. Each
    horizontal axis: initial error ~ N(0, initial_sigma_m^2), then a random walk of
    ``drift_m_per_sqrt_s`` m per sqrt(s). Altitude and the reported velocities get white noise.
    """

    type: Literal["ins"]
    initial_sigma_m: float = Field(default=0.0, ge=0.0, le=1e5, description="initial horizontal error SD, m")
    drift_m_per_sqrt_s: float = Field(default=0.0, ge=0.0, le=100.0, description="random walk, m/sqrt(s)")
    altitude_sigma_m: float = Field(default=0.0, ge=0.0, le=1e4, description="white altitude noise, m")
    velocity_sigma_mps: float = Field(default=0.0, ge=0.0, le=100.0, description="white velocity noise, m/s")
    report_velocity: bool = Field(default=True, description="fill vx_mps, vz_mps, vh_mps")


Sensor = Annotated[SpeedLogParams | HeadingParams | DepthParams | InsParams, Field(discriminator="type")]


class SensorStream:
    """Samples of one sensor: stamps, true states and errors precomputed at construction, messages lazily."""

    def __init__(
        self,
        spec: SpeedLogParams | HeadingParams | DepthParams | InsParams,
        platform: str,
        trajectory: Trajectory,
        rng: np.random.Generator,
        context: ScenarioContext,
    ) -> None:
        self.spec = spec
        self.key = keys.sensor(platform, spec.type, spec.id)
        self.context = context
        self.stamps = sample_stamps_ns(spec.rate_hz, context.duration_ns, spec.start_s, budget=(context, self.key))
        self.truth = trajectory.states(self.stamps / NS_PER_S)
        self.dt_s = 1.0 / spec.rate_hz
        n = self.stamps.size
        self.errors: dict[str, np.ndarray] = {}
        if isinstance(spec, SpeedLogParams):
            for axis, bias in zip(("forward", "starboard", "down"), spec.bias_mps, strict=True):
                self.errors[axis] = bias + white(rng, n, spec.sigma_mps)
        elif isinstance(spec, HeadingParams):
            self.errors["gm"] = gauss_markov.path(rng, n, math.radians(spec.gm_sigma_deg), spec.gm_tau_s, self.dt_s)
            self.errors["white"] = white(rng, n, math.radians(spec.white_sigma_deg))
            self.errors["heading"] = math.radians(spec.bias_deg) + self.errors["gm"] + self.errors["white"]
        elif isinstance(spec, DepthParams):
            self.errors["depth"] = spec.bias_m + white(rng, n, spec.sigma_m)
        else:
            for axis in ("x", "z"):
                self.errors[axis] = random_walk(rng, n, spec.initial_sigma_m, spec.drift_m_per_sqrt_s, self.dt_s)
            self.errors["h"] = white(rng, n, spec.altitude_sigma_m)
            for axis in ("vx", "vz", "vh"):
                self.errors[axis] = white(rng, n, spec.velocity_sigma_mps)

    def columns(self) -> tuple[type[Message], dict[str, np.ndarray]]:
        """The message type and the value of each of its fields per sample (measured = true + error)."""
        spec, tr, err = self.spec, self.truth, self.errors
        ve, vn, vu = tr.velocity_mps[:, 0], tr.velocity_mps[:, 1], tr.velocity_mps[:, 2]
        e, n, u = tr.position_m[:, 0], tr.position_m[:, 1], tr.position_m[:, 2]
        h = tr.heading_rad
        if isinstance(spec, SpeedLogParams):
            return SpeedLog, {
                "v_forward_mps": ve * np.sin(h) + vn * np.cos(h) + err["forward"],
                "v_starboard_mps": ve * np.cos(h) - vn * np.sin(h) + err["starboard"],
                "v_down_mps": -vu + err["down"],
            }
        if isinstance(spec, HeadingParams):
            return Heading, {"heading_rad": np.mod(h + err["heading"], TWO_PI)}
        if isinstance(spec, DepthParams):
            return Depth, {"depth_m": -u + err["depth"]}
        cols = {"x_m": n + err["x"], "z_m": e + err["z"], "h_m": u + err["h"]}
        if spec.report_velocity:
            cols.update(vx_mps=vn + err["vx"], vz_mps=ve + err["vz"], vh_mps=vu + err["vh"])
        return InsSample, cols

    def column_stream(self) -> ColumnStream:
        """The samples as a :class:`ColumnStream` (the message type, each field per sample, the constant fields)."""
        model, cols = self.columns()
        constant: dict[str, object] = {}
        if isinstance(self.spec, SpeedLogParams):
            constant = {"avg_interval_s": self.dt_s, "bottom_lock": self.spec.type == "dvl"}
        return ColumnStream(self.key, model, self.context.frame_id, self.stamps, cols, constant)

    def events(self) -> Iterator[Event]:
        return self.column_stream().events()
