"""Pure truth + measurement simulation of the digest's test flight (digest §4 harness), with a numpy Generator.

* **World:** a terrain of one of the digest's types on the map grid plus a margin (the truth, cell-centre
  values, read bilinearly at the true position), and the reference map ``DEM = truth + white noise``.
* **Flight:** straight at constant ground speed along ``heading_deg`` (clockwise from +x towards +z;
  0 = along +x, the digest's harness) and constant true altitude (max terrain + clearance); the
  INS-indicated start is a random point inside the start cell. Or any **path** (:class:`PathSamples`: the
  true positions and velocities at every tick, from waypoints or a recorded track), with the same INS error
  model on top.
* **INS errors** (sign convention true = indicated + d): constant initial horizontal offset, uniform in
  +-``offset_max_cells`` per axis, drifting with a constant horizontal velocity error ~ N(0, sigma_vh) per
  axis; vertical errors dh(t) = dh0 + dV0 t + da t^2/2.
* **Radio altimeter:** h_ra = h_true - h_terrain(x_true, z_true) + N(0, sigma_v), plus injected failures:
  additive false data with the valid flag kept true, dropouts (flag false), NaN samples, INS gaps.

:meth:`SimulatedFlight.messages` yields the schemas' input messages (``InsSample`` then ``RadioAltimeter``
per tick, stamps in ``header.stamp_ns``), so a scenario player can wrap it; the arrays and
:meth:`SimulatedFlight.truth_at` give the truth for scoring.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from schemas import Header, InsSample, Message, RadioAltimeter, Truth

from .geometry import F64, Bool, bilinear
from .maps import ReferenceMap
from .terrain import TerrainType, make_terrain


class FailureSpec(BaseModel):
    """One injected failure on [onset, onset + duration) seconds after the start of the flight."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["additive", "dropout", "nan", "ins_gap"]
    onset_s: float = Field(ge=0.0)
    duration_s: float = Field(gt=0.0)
    amplitude_m: float = Field(default=0.0, description="additive RA error (kind 'additive'), m")


class FlightScenario(BaseModel):
    """Parameters of one simulated flight and its world (defaults: the digest's common harness)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = "informative"
    terrain: TerrainType = "informative"
    map_cells: tuple[int, int] = (200, 101)
    cell_m: float = 125.0
    margin_cells: int = 48
    H: float = 0.6
    corr_cells: float | None = None
    rms_inc_m: float = 12.0
    flat_rms_inc_m: float = 0.3
    periodic_amp_m: float = 40.0
    periodic_cells: float = 10.0
    start_cell: tuple[int, int] = (70, 70)
    heading_deg: float = 0.0
    speed_mps: float = 200.0
    clearance_m: float = 300.0
    rate_hz: float = 20.0
    duration_s: float | None = Field(default=None, description="None: until the hypothesis patch leaves the map")
    stop_half_width: int = 25
    offset_max_cells: float = 20.0
    sigma_vh_mps: float = 0.3
    sigma_dh0_m: float = 50.0
    sigma_dV0_mps: float = 0.5  # noqa: N815 - dV0 of the digest
    sigma_da_mps2: float = 1e-3
    sigma_v_m: float = 2.0
    sigma_map_m: float = 3.0
    failures: tuple[FailureSpec, ...] = ()
    n_nan_samples: int = 0
    t0_s: float = 100.0
    ins_velocity: bool = True


@dataclass
class World:
    """The truth terrain (with margin) and the reference map built from it.

    ``truth`` holds cell-centre heights on a grid of ``truth_cell_m`` cells whose cell (0, 0) has its corner
    at ``truth_origin_m`` (x0, z0). By default (None) that is the reference map's grid extended by
    ``margin`` cells on every side (the synthetic worlds); a world read from a DEM file gives its own.
    """

    truth: F64  # cell-centre truth heights on the map grid plus margin on every side
    margin: int
    ref_map: ReferenceMap
    truth_origin_m: tuple[float, float] | None = None
    truth_cell_m: float | None = None

    @property
    def truth_geometry(self) -> tuple[float, float, float]:
        """(x0, z0, cell) of the truth grid's cell (0, 0) corner and its cell size, m."""
        ref = self.ref_map
        cell = self.truth_cell_m if self.truth_cell_m is not None else ref.cell_m
        if self.truth_origin_m is not None:
            return self.truth_origin_m[0], self.truth_origin_m[1], cell
        return ref.x0_m - self.margin * cell, ref.z0_m - self.margin * cell, cell

    def terrain_height(self, x: F64, z: F64) -> F64:
        """True terrain height at map coordinates (bilinear through the truth cell centres; NaN over voids)."""
        if self.truth_origin_m is None and self.truth_cell_m is None:  # the synthetic world, as always computed
            ref = self.ref_map
            u = (x - ref.x0_m) / ref.cell_m - 0.5 + self.margin
            v = (z - ref.z0_m) / ref.cell_m - 0.5 + self.margin
        else:
            x0, z0, cell = self.truth_geometry
            u = (x - x0) / cell - 0.5
            v = (z - z0) / cell - 0.5
        return bilinear(self.truth, np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))


@dataclass
class PathSamples:
    """A true path at the flight's ticks, in the map frame: tau (s since the start), x, z (m), their rates
    (m/s) and optionally the true altitude h (m) and its rate (None: constant max terrain + clearance)."""

    tau: F64
    x: F64
    z: F64
    vx: F64
    vz: F64
    h: F64 | None = None
    vh: F64 | None = None


def make_world(sc: FlightScenario, rng: np.random.Generator) -> World:
    """Terrain of ``sc.terrain`` (truth) and the DEM = truth + N(0, sigma_map) on the map cells."""
    n_i, n_j = sc.map_cells
    m = sc.margin_cells
    truth = make_terrain(
        sc.terrain,
        (n_i + 2 * m, n_j + 2 * m),
        rng,
        H=sc.H,
        rms_inc_m=sc.rms_inc_m,
        flat_rms_inc_m=sc.flat_rms_inc_m,
        periodic_amp_m=sc.periodic_amp_m,
        periodic_cells=sc.periodic_cells,
        corr_cells=sc.corr_cells,
    )
    dem = truth[m : m + n_i, m : m + n_j] + rng.normal(0.0, sc.sigma_map_m, (n_i, n_j))
    return World(truth=truth, margin=m, ref_map=ReferenceMap(dem=dem, x0_m=0.0, z0_m=0.0, cell_m=sc.cell_m))


@dataclass
class SimulatedFlight:
    """Time series of one flight (tau = time since the start, s; stamps are t0 + tau)."""

    scenario: FlightScenario
    world: World
    tau: F64
    x_true: F64
    z_true: F64
    h_true: F64
    x_ins: F64
    z_ins: F64
    h_ins: F64
    vx_ins: F64
    vz_ins: F64
    vh_ins: F64
    h_ra: F64
    ra_valid: Bool
    ins_present: Bool
    dx0: float
    dz0: float
    dvx: float
    dvz: float
    dh0: float
    dV0: float  # noqa: N815 - the digest's symbol
    da: float
    vx_true: F64 | None = None  # m/s; None: the straight flight's constant speed along x
    vz_true: F64 | None = None
    vh_true: F64 | None = None

    def true_velocity(self, k: int) -> list[float]:
        """[vx, vz, vh] of the truth at tick k, m/s."""
        if self.vx_true is None or self.vz_true is None:
            return [self.scenario.speed_mps, 0.0, 0.0]
        vh = float(self.vh_true[k]) if self.vh_true is not None else 0.0
        return [float(self.vx_true[k]), float(self.vz_true[k]), vh]

    @property
    def t0_s(self) -> float:
        """Scenario-clock time of the first tick, s."""
        return self.scenario.t0_s

    @property
    def cell_m(self) -> float:
        return self.scenario.cell_m

    @property
    def t(self) -> F64:
        """Scenario-clock time of each tick, s."""
        out: F64 = self.scenario.t0_s + self.tau
        return out

    def stamp_ns(self, k: int) -> int:
        return round((self.scenario.t0_s + float(self.tau[k])) * 1e9)

    def truth_at(self, t: float) -> dict[str, float]:
        """True corrections at scenario time t: dx, dz (m), dh (m), dV (m/s) (true = indicated + d)."""
        tau = t - self.scenario.t0_s
        return {
            "dx": self.dx0 + self.dvx * tau,
            "dz": self.dz0 + self.dvz * tau,
            "dh": self.dh0 + self.dV0 * tau + 0.5 * self.da * tau * tau,
            "dV": self.dV0 + self.da * tau,
        }

    def messages(self, include_truth: bool = False, truth_every: int = 20) -> Iterator[Message]:
        """InsSample then RadioAltimeter per tick (optionally a Truth every ``truth_every`` ticks)."""
        sc = self.scenario
        for k in range(self.tau.size):
            stamp = self.stamp_ns(k)
            if self.ins_present[k]:
                yield InsSample(
                    header=Header(stamp_ns=stamp, frame_id="map", source="sim/ins"),
                    x_m=float(self.x_ins[k]),
                    z_m=float(self.z_ins[k]),
                    h_m=float(self.h_ins[k]),
                    vx_mps=float(self.vx_ins[k]) if sc.ins_velocity else None,
                    vz_mps=float(self.vz_ins[k]) if sc.ins_velocity else None,
                    vh_mps=float(self.vh_ins[k]) if sc.ins_velocity else None,
                )
            h = float(self.h_ra[k])
            hdr = Header(stamp_ns=stamp, frame_id="map", source="sim/ra")
            if math.isfinite(h):
                yield RadioAltimeter(header=hdr, h_agl_m=max(h, 0.0), valid=bool(self.ra_valid[k]))
            else:  # a NaN sample as a corrupt sensor would produce it (bypasses validation on purpose)
                yield RadioAltimeter.model_construct(header=hdr, h_agl_m=h, valid=bool(self.ra_valid[k]))
            if include_truth and k % truth_every == 0:
                d = self.truth_at(sc.t0_s + float(self.tau[k]))
                yield Truth(
                    header=Header(stamp_ns=stamp, frame_id="map", source="sim/truth"),
                    platform="aircraft",
                    position_m=[float(self.x_true[k]), float(self.z_true[k]), float(self.h_true[k])],
                    velocity_mps=self.true_velocity(k),
                    extra={"dx_m": d["dx"], "dz_m": d["dz"], "dh_m": d["dh"], "dV_mps": d["dV"]},
                )


def _straight_duration(
    sc: FlightScenario, ref: ReferenceMap, x_ins0: float, z_ins0: float, v: tuple[float, float]
) -> float:
    """Time until the INS cell's hypothesis patch would leave the map, flying at INS velocity ``v`` (vx, vz)."""
    cell = sc.cell_m
    n_i, n_j = ref.shape
    x_end = ref.x0_m + (n_i - sc.stop_half_width) * cell
    if sc.heading_deg == 0.0:  # the digest's harness along +x, exactly as it has always been computed
        return (x_end - x_ins0) / v[0]
    times = []
    for pos, vel, lo, hi in (
        (x_ins0, v[0], ref.x0_m + sc.stop_half_width * cell, x_end),
        (z_ins0, v[1], ref.z0_m + sc.stop_half_width * cell, ref.z0_m + (n_j - sc.stop_half_width) * cell),
    ):
        if vel > 1e-9:
            times.append((hi - pos) / vel)
        elif vel < -1e-9:
            times.append((lo - pos) / vel)
    return max(min(times), 0.0) if times else 0.0


def simulate_flight(
    sc: FlightScenario, world: World, rng: np.random.Generator, path: PathSamples | None = None
) -> SimulatedFlight:
    """Draw the INS errors and sensor noise of one flight over ``world``.

    Without ``path``: the straight flight of the scenario (start cell, heading, speed). With ``path``: the
    true positions are the path's, the INS errors the same model on top (the start cell and heading are not
    used). Where the truth terrain is a void the radio altimeter reports its valid flag false.
    """
    ref = world.ref_map
    cell = sc.cell_m
    if path is None:
        I0, J0 = sc.start_cell
        x_ins0 = ref.x0_m + (I0 + rng.uniform()) * cell
        z_ins0 = ref.z0_m + (J0 + rng.uniform()) * cell
    dx0, dz0 = rng.uniform(-sc.offset_max_cells, sc.offset_max_cells, 2) * cell
    dvx, dvz = rng.normal(0.0, sc.sigma_vh_mps, 2) if sc.sigma_vh_mps > 0 else (0.0, 0.0)
    dh0 = rng.normal(0.0, sc.sigma_dh0_m)
    dV0 = rng.normal(0.0, sc.sigma_dV0_mps)
    da = rng.normal(0.0, sc.sigma_da_mps2)
    h_level = float(np.nanmax(world.truth)) + sc.clearance_m
    vx_true = vz_true = vh_true = None
    if path is None:
        cos_h, sin_h = math.cos(math.radians(sc.heading_deg)), math.sin(math.radians(sc.heading_deg))
        if sc.heading_deg == 0.0:
            cos_h, sin_h = 1.0, 0.0
        v_ins = sc.speed_mps - dvx
        if sc.duration_s is not None:
            duration = sc.duration_s
        else:  # until the INS cell's hypothesis patch would leave the map
            duration = _straight_duration(
                sc, ref, x_ins0, z_ins0, (sc.speed_mps * cos_h - dvx, sc.speed_mps * sin_h - dvz)
            )
        n = max(math.floor(duration * sc.rate_hz), 1)
        tau = np.arange(n, dtype=np.float64) / sc.rate_hz
        if sin_h == 0.0 and cos_h == 1.0:
            x_true = x_ins0 + dx0 + sc.speed_mps * tau
            z_true = np.full(n, z_ins0 + dz0)
        else:
            x_true = x_ins0 + dx0 + sc.speed_mps * cos_h * tau
            z_true = z_ins0 + dz0 + sc.speed_mps * sin_h * tau
            vx_true, vz_true = np.full(n, sc.speed_mps * cos_h), np.full(n, sc.speed_mps * sin_h)
        h_true = np.full(n, h_level)
        vx_ins = np.full(n, v_ins) if vx_true is None else vx_true - dvx
        vz_ins = np.full(n, -dvz) if vz_true is None else vz_true - dvz
    else:
        tau = np.asarray(path.tau, dtype=np.float64)
        n = tau.size
        x_true, z_true = np.asarray(path.x, dtype=np.float64), np.asarray(path.z, dtype=np.float64)
        vx_true, vz_true = np.asarray(path.vx, dtype=np.float64), np.asarray(path.vz, dtype=np.float64)
        h_true = np.full(n, h_level) if path.h is None else np.asarray(path.h, dtype=np.float64)
        vh_true = None if path.vh is None else np.asarray(path.vh, dtype=np.float64)
        vx_ins, vz_ins = vx_true - dvx, vz_true - dvz
    dx = dx0 + dvx * tau
    dz = dz0 + dvz * tau
    x_ins = x_true - dx
    z_ins = z_true - dz
    dh = dh0 + dV0 * tau + 0.5 * da * tau * tau
    dV = dV0 + da * tau
    h_ins = h_true - dh
    vh_ins = (0.0 if vh_true is None else vh_true) - dV
    terrain = world.terrain_height(x_true, z_true)
    h_ra = h_true - terrain + rng.normal(0.0, sc.sigma_v_m, n)
    ra_valid = np.isfinite(terrain)  # over a void of the truth DEM the altimeter has no valid height
    if not ra_valid.all():
        h_ra = np.where(ra_valid, h_ra, 0.0)
    ins_present = np.ones(n, dtype=bool)
    for f in sc.failures:
        on = (tau >= f.onset_s) & (tau < f.onset_s + f.duration_s)
        if f.kind == "additive":
            h_ra[on] += f.amplitude_m
        elif f.kind == "dropout":
            ra_valid[on] = False
        elif f.kind == "nan":
            h_ra[on] = np.nan
        else:
            ins_present[on] = False
    if sc.n_nan_samples:
        h_ra[rng.choice(n, size=min(sc.n_nan_samples, n), replace=False)] = np.nan
    return SimulatedFlight(
        scenario=sc,
        world=world,
        tau=tau,
        x_true=x_true,
        z_true=z_true,
        h_true=h_true,
        x_ins=x_ins,
        z_ins=z_ins,
        h_ins=h_ins,
        vx_ins=np.asarray(vx_ins, dtype=np.float64),
        vz_ins=np.asarray(vz_ins, dtype=np.float64),
        vh_ins=vh_ins,
        h_ra=h_ra,
        ra_valid=np.array(ra_valid, dtype=bool),
        ins_present=ins_present,
        dx0=float(dx0),
        dz0=float(dz0),
        dvx=float(dvx),
        dvz=float(dvz),
        dh0=float(dh0),
        dV0=float(dV0),
        da=float(da),
        vx_true=vx_true,
        vz_true=vz_true,
        vh_true=vh_true,
    )


def simulate(sc: FlightScenario, seed: int) -> SimulatedFlight:
    """World and flight from one seed (world first, then the flight, from independent child streams)."""
    ss = np.random.SeedSequence(seed)
    w_seed, f_seed = ss.spawn(2)
    world = make_world(sc, np.random.default_rng(w_seed))
    return simulate_flight(sc, world, np.random.default_rng(f_seed))
