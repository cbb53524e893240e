"""Pure truth + measurement simulation of the digest's test flight (digest §4 harness), with a numpy Generator.

* **World:** a terrain of one of the digest's types on the map grid plus a margin (the truth, cell-centre
  values, read bilinearly at the true position), and the reference map ``DEM = truth + white noise``.
* **Flight:** straight along +x at constant ground speed and constant true altitude (max terrain +
  clearance); the INS-indicated start is a random point inside the start cell.
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
    rms_inc_m: float = 12.0
    flat_rms_inc_m: float = 0.3
    periodic_amp_m: float = 40.0
    periodic_cells: float = 10.0
    start_cell: tuple[int, int] = (70, 70)
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
    """The truth terrain (with margin) and the reference map built from it."""

    truth: F64  # cell-centre truth heights on the map grid plus margin on every side
    margin: int
    ref_map: ReferenceMap

    def terrain_height(self, x: F64, z: F64) -> F64:
        """True terrain height at map coordinates (bilinear through the truth cell centres)."""
        ref = self.ref_map
        u = (x - ref.x0_m) / ref.cell_m - 0.5 + self.margin
        v = (z - ref.z0_m) / ref.cell_m - 0.5 + self.margin
        return bilinear(self.truth, np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))


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
                    velocity_mps=[sc.speed_mps, 0.0, 0.0],
                    extra={"dx_m": d["dx"], "dz_m": d["dz"], "dh_m": d["dh"], "dV_mps": d["dV"]},
                )


def simulate_flight(sc: FlightScenario, world: World, rng: np.random.Generator) -> SimulatedFlight:
    """Draw the INS errors and sensor noise of one flight over ``world``."""
    ref = world.ref_map
    cell = sc.cell_m
    I0, J0 = sc.start_cell
    x_ins0 = ref.x0_m + (I0 + rng.uniform()) * cell
    z_ins0 = ref.z0_m + (J0 + rng.uniform()) * cell
    dx0, dz0 = rng.uniform(-sc.offset_max_cells, sc.offset_max_cells, 2) * cell
    dvx, dvz = rng.normal(0.0, sc.sigma_vh_mps, 2) if sc.sigma_vh_mps > 0 else (0.0, 0.0)
    dh0 = rng.normal(0.0, sc.sigma_dh0_m)
    dV0 = rng.normal(0.0, sc.sigma_dV0_mps)
    da = rng.normal(0.0, sc.sigma_da_mps2)
    v_ins = sc.speed_mps - dvx
    if sc.duration_s is not None:
        duration = sc.duration_s
    else:  # until the INS cell's hypothesis patch would leave the map
        x_end = ref.x0_m + (sc.map_cells[0] - sc.stop_half_width) * cell
        duration = (x_end - x_ins0) / v_ins
    n = max(math.floor(duration * sc.rate_hz), 1)
    tau = np.arange(n, dtype=np.float64) / sc.rate_hz
    x_true = x_ins0 + dx0 + sc.speed_mps * tau
    z_true = np.full(n, z_ins0 + dz0)
    dx = dx0 + dvx * tau
    dz = dz0 + dvz * tau
    x_ins = x_true - dx
    z_ins = z_true - dz
    h_level = float(np.max(world.truth)) + sc.clearance_m
    h_true = np.full(n, h_level)
    dh = dh0 + dV0 * tau + 0.5 * da * tau * tau
    dV = dV0 + da * tau
    h_ins = h_true - dh
    vh_ins = 0.0 - dV
    h_ra = h_true - world.terrain_height(x_true, z_true) + rng.normal(0.0, sc.sigma_v_m, n)
    ra_valid = np.ones(n, dtype=bool)
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
        vx_ins=np.full(n, v_ins),
        vz_ins=np.full(n, -dvz),
        vh_ins=vh_ins,
        h_ra=h_ra,
        ra_valid=ra_valid,
        ins_present=ins_present,
        dx0=float(dx0),
        dz0=float(dz0),
        dvx=float(dvx),
        dvz=float(dvz),
        dh0=float(dh0),
        dV0=float(dV0),
        da=float(da),
    )


def simulate(sc: FlightScenario, seed: int) -> SimulatedFlight:
    """World and flight from one seed (world first, then the flight, from independent child streams)."""
    ss = np.random.SeedSequence(seed)
    w_seed, f_seed = ss.spawn(2)
    world = make_world(sc, np.random.default_rng(w_seed))
    return simulate_flight(sc, world, np.random.default_rng(f_seed))
