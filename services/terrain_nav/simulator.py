"""The player's ``terrain_nav`` simulator: the digest's test flight (§4 harness) over a synthetic terrain.

A thin wrapper of the core's pure simulation (:mod:`services.terrain_nav.simulation`): the world (a terrain
of one of the digest's types, the truth with a margin, the reference map ``DEM = truth + N(0, sigma_map)``),
the straight flight along +x at constant speed and altitude, the INS error model (initial offset, drifting
horizontal velocity error, vertical errors), the radio-altimeter noise and the injected failures (additive
false data with the valid flag kept, dropouts, NaN samples, INS gaps). A start cell near the map edge
flies the aircraft into and out of the correction zone.

Keys (``<platform>``, ``<ins_id>`` and ``<radalt_id>`` from the parameters):

* ``fixstream/sensor/<platform>/ins/<ins_id>``: :class:`schemas.InsSample` at ``rate_hz`` (x = north,
  z = east in the map frame; h up);
* ``fixstream/sensor/<platform>/radalt/<radalt_id>``: :class:`schemas.RadioAltimeter` at ``rate_hz``;
* ``fixstream/truth/<platform>``: :class:`schemas.Truth` at ``truth_rate_hz``: ``position_m`` and
  ``velocity_mps`` as [east, north, up] = [z, x, h], and ``extra``: the true corrections ``dx_m``,
  ``dz_m``, ``dh_m``, ``dV_mps`` (true = INS + d) and ``terrain_seed``.

**The map.** The estimator service must hold the same reference map as the simulator. The world is a pure
function of the terrain parameters and ``terrain_seed`` (it equals the world of
``simulation.simulate(scenario, terrain_seed)``), so a scenario that is played to the service fixes
``terrain_seed`` and names the service's map file in ``map_file``: the simulator loads that file, checks
it against the generated DEM (1 µm) and uses it as the reference map. The map files are written by
``python -m services.terrain_nav.mapfiles SCENARIO.yaml ...``. Without ``terrain_seed`` every
Monte-Carlo run draws its own terrain (for ``fixstream mc`` only); its seed goes out in the Truth extras
so the Monte-Carlo plugin rebuilds the same map.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, Field, model_validator

from schemas import Header, InsSample, Message, Truth
from services.player.simulators import (
    NS_PER_S,
    Event,
    ScenarioContext,
    SimParams,
    TruthState,
    child_rng,
    register,
)
from services.player.simulators.recorded_track import TrackFileParams, load_cached
from shared import keys

from .maps import ReferenceMap, load_map
from .simulation import FailureSpec, FlightScenario, PathSamples, SimulatedFlight, World, make_world, simulate_flight
from .terrain import TerrainType
from .topics import INS_KIND, RADALT_KIND

KIND = "terrain_nav"
#: a drawn terrain seed stays below 2**31, so it is exact in the float ``Truth.extra``
TERRAIN_SEED_MAX = 2**31
#: largest difference (m) between a map file and the generated DEM that still counts as the same map
MAP_TOLERANCE_M = 1e-6


def _chunk(v: str) -> str:
    return keys.chunk(v)


KeyChunk = Annotated[str, AfterValidator(_chunk)]


class TerrainFailure(SimParams):
    """One injected failure on ``[onset_s, onset_s + duration_s)`` after the first sample of the flight."""

    kind: Literal["additive", "dropout", "nan", "ins_gap"] = Field(
        description="additive: RA + amplitude with the valid flag kept; dropout: RA valid flag false; "
        "nan: RA height NaN; ins_gap: no INS sample"
    )
    onset_s: float = Field(ge=0.0, le=1e6, description="start, s after the first sample")
    duration_s: float = Field(gt=0.0, le=1e6, description="length, s")
    amplitude_m: float = Field(default=0.0, ge=-1e4, le=1e4, description="additive RA error (kind additive), m")


class TerrainWaypoint(SimParams):
    """A waypoint: local map metres ``position_m: [east, north]`` or geodetic ``lat_deg``/``lon_deg`` (WGS84)."""

    position_m: list[float] | None = Field(
        default=None, min_length=2, max_length=2, description="[east, north] in the map frame (z, x), m"
    )
    lat_deg: float | None = Field(default=None, ge=-90.0, le=90.0, description="latitude, deg (WGS84)")
    lon_deg: float | None = Field(default=None, ge=-180.0, le=180.0, description="longitude, deg (WGS84)")
    alt_m: float | None = Field(default=None, ge=-1000.0, le=30_000.0, description="altitude (track_altitude), m")
    speed_mps: float | None = Field(default=None, gt=0.0, le=1000.0, description="speed on the way here, m/s")

    @model_validator(mode="after")
    def _one_position(self) -> TerrainWaypoint:
        geo = self.lat_deg is not None or self.lon_deg is not None
        if geo and (self.lat_deg is None or self.lon_deg is None):
            raise ValueError("a geodetic waypoint needs both lat_deg and lon_deg")
        if geo == (self.position_m is not None):
            raise ValueError("give either position_m or lat_deg/lon_deg")
        return self


class TerrainFlightParams(SimParams):
    """Parameters of the ``terrain_nav`` simulator (defaults: the digest's common test harness, §4)."""

    platform: KeyChunk = Field(description="vehicle id in the keys; the estimator instance that follows it")
    ins_id: KeyChunk = Field(default="ins0", description="INS sensor id (last key chunk)")
    radalt_id: KeyChunk = Field(default="ra0", description="radio-altimeter sensor id (last key chunk)")
    start_s: float = Field(default=0.0, ge=0.0, le=1e6, description="scenario time of the first sample, s")
    truth_rate_hz: float = Field(default=1.0, gt=0.0, le=1000.0, description="Truth rate, Hz (<= rate_hz)")
    # --- world -----------------------------------------------------------------------------------------
    terrain: TerrainType = Field(default="informative", description="informative, flat, ridge_x, ridge_z, periodic")
    terrain_seed: int | None = Field(
        default=None, ge=0, lt=2**53, description="seed of the world (terrain and map noise); null: drawn per run"
    )
    map_file: str | None = Field(
        default=None,
        max_length=1024,
        description="the estimator's map: synthetic terrain: the service's .npy, checked against the terrain; "
        "with terrain_file: another DEM (.npy or GeoTIFF at cell_m) used as is",
    )
    terrain_file: str | None = Field(
        default=None,
        max_length=1024,
        description="a DEM as the truth terrain: GeoTIFF in any CRS (reprojected to cell_m cells) or .npy + sidecar",
    )
    terrain_x_axis: Literal["north", "east"] = Field(
        default="north", description="terrain_file/map_file: the map's x axis along north (z = east) or east"
    )
    map_cells: list[int] = Field(
        default_factory=lambda: [200, 101], min_length=2, max_length=2, description="map size [n_x, n_z], cells"
    )
    cell_m: float = Field(default=125.0, gt=0.0, le=10_000.0, description="map cell size, m")
    margin_cells: int = Field(default=48, ge=0, le=1000, description="truth terrain beyond the map edge, cells")
    hurst: float = Field(default=0.6, gt=0.0, lt=1.0, description="Hurst exponent H of the fBm terrain")
    correlation_cells: float | None = Field(
        default=None, gt=0.0, le=1e5, description="von Karman correlation length of the terrain, cells (null: fBm)"
    )
    rms_increment_m: float = Field(default=12.0, ge=0.0, le=1000.0, description="RMS adjacent-cell height change, m")
    flat_rms_increment_m: float = Field(default=0.3, ge=0.0, le=1000.0, description="the same for 'flat', m")
    periodic_amplitude_m: float = Field(default=40.0, ge=0.0, le=1000.0, description="'periodic' amplitude, m")
    periodic_period_cells: float = Field(default=10.0, gt=0.0, le=1000.0, description="'periodic' period, cells")
    sigma_map_m: float = Field(default=3.0, ge=0.0, le=100.0, description="DEM error per cell (1 sigma), m")
    # --- flight ----------------------------------------------------------------------------------------
    start_cell: list[int] | None = Field(
        default=None,
        min_length=2,
        max_length=2,
        description="INS start cell [I, J]; null: [70, 70] on synthetic terrain, the informative line on a file",
    )
    heading_deg: float | None = Field(
        default=None,
        ge=-360.0,
        le=360.0,
        description="straight flight: clockwise from +x (north) to +z (east), deg; null: 0, or the informative line",
    )
    waypoints: list[TerrainWaypoint] = Field(
        default_factory=list, max_length=10_000, description="fly these instead of a straight line"
    )
    turn_rate_dps: float = Field(default=3.0, gt=0.0, le=30.0, description="turn rate between waypoints, deg/s")
    track: TrackFileParams | None = Field(default=None, description="fly a recorded trajectory (truth) instead")
    track_altitude: bool = Field(
        default=False,
        description="true altitude from the waypoints/track (in the DEM's vertical datum) instead of "
        "max terrain + clearance",
    )
    speed_mps: float = Field(default=200.0, gt=0.0, le=1000.0, description="ground speed, m/s")
    clearance_m: float = Field(default=300.0, ge=0.0, le=20_000.0, description="altitude above the highest terrain, m")
    rate_hz: float = Field(default=20.0, gt=0.0, le=1000.0, description="INS and RA sample rate, Hz")
    flight_duration_s: float | None = Field(
        default=None, gt=0.0, le=1e6, description="s; null: until the hypothesis patch would leave the map"
    )
    stop_half_width_cells: int = Field(default=25, ge=0, le=1000, description="patch half-width of the stop rule")
    # --- INS errors (true = indicated + d) ------------------------------------------------------------
    offset_max_cells: float = Field(default=20.0, ge=0.0, le=1000.0, description="initial offset, uniform +-, cells")
    sigma_vh_mps: float = Field(default=0.3, ge=0.0, le=100.0, description="horizontal velocity error per axis, m/s")
    sigma_dh0_m: float = Field(default=50.0, ge=0.0, le=10_000.0, description="initial altitude error, m")
    sigma_dv0_mps: float = Field(default=0.5, ge=0.0, le=100.0, description="initial vertical-speed error, m/s")
    sigma_da_mps2: float = Field(default=1e-3, ge=0.0, le=10.0, description="vertical acceleration error, m/s^2")
    report_velocity: bool = Field(default=True, description="fill vx/vz/vh of the INS samples")
    # --- radio altimeter ---------------------------------------------------------------------------------
    sigma_v_m: float = Field(default=2.0, ge=0.0, le=100.0, description="RA white noise per sample, m")
    failures: list[TerrainFailure] = Field(default_factory=list, max_length=1000)
    nan_samples: int = Field(default=0, ge=0, le=1_000_000, description="RA samples set to NaN at random")

    @model_validator(mode="after")
    def _consistent(self) -> TerrainFlightParams:
        if min(self.map_cells) < 2:
            raise ValueError("map_cells: at least 2 x 2 cells")
        if self.terrain_file is None and not all(0 <= c < n for c, n in zip(self.start, self.map_cells, strict=True)):
            raise ValueError(f"start_cell {self.start_cell} is not on the {self.map_cells} map")
        if self.truth_rate_hz > self.rate_hz:
            raise ValueError("truth_rate_hz must not exceed rate_hz")
        if self.map_file is not None and self.terrain_seed is None and self.terrain_file is None:
            raise ValueError("map_file needs a fixed terrain_seed (a drawn terrain has no map file)")
        if self.waypoints and self.track is not None:
            raise ValueError("give either waypoints or a track, not both")
        if len(self.waypoints) == 1:
            raise ValueError("waypoints: at least 2 (the first is where the flight starts)")
        if self.terrain_file is None and any(w.lat_deg is not None for w in self.waypoints):
            raise ValueError("geodetic waypoints need a terrain_file with a CRS (synthetic maps are local)")
        return self

    @property
    def start(self) -> list[int]:
        """The INS start cell of a straight flight on synthetic terrain ([70, 70] unless given)."""
        return self.start_cell if self.start_cell is not None else [70, 70]

    @property
    def flies_path(self) -> bool:
        return bool(self.waypoints) or self.track is not None

    def flight_scenario(self, name: str = KIND) -> FlightScenario:
        """The core's :class:`FlightScenario` of these parameters (stamps start at ``start_s``)."""
        return FlightScenario(
            name=name,
            terrain=self.terrain,
            map_cells=(self.map_cells[0], self.map_cells[1]),
            cell_m=self.cell_m,
            margin_cells=self.margin_cells,
            H=self.hurst,
            corr_cells=self.correlation_cells,
            rms_inc_m=self.rms_increment_m,
            flat_rms_inc_m=self.flat_rms_increment_m,
            periodic_amp_m=self.periodic_amplitude_m,
            periodic_cells=self.periodic_period_cells,
            start_cell=(self.start[0], self.start[1]),
            heading_deg=self.heading_deg if self.heading_deg is not None else 0.0,
            speed_mps=self.speed_mps,
            clearance_m=self.clearance_m,
            rate_hz=self.rate_hz,
            duration_s=self.flight_duration_s,
            stop_half_width=self.stop_half_width_cells,
            offset_max_cells=self.offset_max_cells,
            sigma_vh_mps=self.sigma_vh_mps,
            sigma_dh0_m=self.sigma_dh0_m,
            sigma_dV0_mps=self.sigma_dv0_mps,
            sigma_da_mps2=self.sigma_da_mps2,
            sigma_v_m=self.sigma_v_m,
            sigma_map_m=self.sigma_map_m,
            failures=tuple(
                FailureSpec(kind=f.kind, onset_s=f.onset_s, duration_s=f.duration_s, amplitude_m=f.amplitude_m)
                for f in self.failures
            ),
            n_nan_samples=self.nan_samples,
            t0_s=self.start_s,
            ins_velocity=self.report_velocity,
        )


# --- the world and its map ---------------------------------------------------------------------------------------


def generated_world(params: TerrainFlightParams, terrain_seed: int) -> World:
    """Truth terrain and DEM of ``params`` for ``terrain_seed`` (= the world of ``simulate(sc, terrain_seed)``).

    With ``terrain_file`` the truth is that DEM (at ``cell_m``) and the map is truth + N(0, sigma_map) per
    cell (voids stay voids), the noise drawn from the same world stream of ``terrain_seed``.
    """
    world_seq = np.random.SeedSequence(terrain_seed).spawn(2)[0]
    rng = np.random.default_rng(world_seq)
    if params.terrain_file is None:
        return make_world(params.flight_scenario(), rng)
    truth = _truth_map(params.terrain_file, params.cell_m, params.terrain_x_axis)
    dem = truth.dem + rng.normal(0.0, params.sigma_map_m, truth.shape) if params.sigma_map_m > 0 else truth.dem
    ref = ReferenceMap(
        dem=dem, x0_m=truth.x0_m, z0_m=truth.z0_m, cell_m=truth.cell_m, datum=truth.datum, crs=truth.crs,
        x_axis=truth.x_axis,
    )  # fmt: skip
    return World(
        truth=np.array(truth.dem), margin=0, ref_map=ref, truth_origin_m=(truth.x0_m, truth.z0_m),
        truth_cell_m=truth.cell_m,
    )  # fmt: skip


@functools.lru_cache(maxsize=8)
def _truth_map(path: str, cell_m: float, x_axis: Literal["north", "east"]) -> ReferenceMap:
    """A DEM file as a map of ``cell_m`` cells (cached: Monte-Carlo runs share it; the DEM is read-only)."""
    return load_map(path, cell_m, x_axis)


def check_same_map(loaded: ReferenceMap, generated: ReferenceMap, where: str) -> None:
    """Raise ValueError if a map file is not the generated DEM (geometry, voids, heights within 1 µm)."""
    problems = []
    if loaded.shape != generated.shape:
        problems.append(f"shape {loaded.shape} != {generated.shape}")
    elif not np.array_equal(loaded.void, generated.void):
        problems.append("the void cells differ")
    else:
        ok = ~loaded.void
        diff = float(np.max(np.abs(loaded.dem[ok] - generated.dem[ok]))) if ok.any() else 0.0
        if diff > MAP_TOLERANCE_M:
            problems.append(f"heights differ by up to {diff:.3g} m")
    for name in ("x0_m", "z0_m", "cell_m"):
        a, b = getattr(loaded, name), getattr(generated, name)
        if not math.isclose(a, b, rel_tol=0.0, abs_tol=1e-9):
            problems.append(f"{name} {a} != {b}")
    if problems:
        raise ValueError(
            f"map_file {where} is not the map of this terrain ({'; '.join(problems)}); "
            "rewrite it with: python -m services.terrain_nav.mapfiles <scenario.yaml>"
        )


def scenario_world(params: TerrainFlightParams, terrain_seed: int) -> World:
    """The world a run flies over; with ``map_file`` its reference map is that file (checked)."""
    world = generated_world(params, terrain_seed)
    if params.map_file is None:
        return world
    if params.terrain_file is not None:  # another DEM for the estimator: used as is
        other = load_map(params.map_file, params.cell_m, params.terrain_x_axis)
        return World(world.truth, world.margin, other, world.truth_origin_m, world.truth_cell_m)
    loaded = load_map(params.map_file)
    check_same_map(loaded, world.ref_map, params.map_file)
    return World(truth=world.truth, margin=world.margin, ref_map=loaded)


def flight_setup(
    params: TerrainFlightParams, world: World, name: str = KIND
) -> tuple[FlightScenario, PathSamples | None]:
    """The flight scenario and, for waypoints or a track, the true path in the map frame.

    On a DEM file without waypoints, track or start cell, the straight flight follows the map's informative
    line (:func:`services.terrain_nav.paths.informative_line`) at the given or the chosen heading.
    """
    from . import paths

    sc = params.flight_scenario(name)
    ref = world.ref_map
    cap = params.flight_duration_s
    if params.waypoints:
        wps = [
            paths.MapWaypoint(
                *paths.map_point(
                    ref,
                    (w.position_m[0], w.position_m[1]) if w.position_m is not None else None,
                    (w.lat_deg, w.lon_deg) if w.lat_deg is not None and w.lon_deg is not None else None,
                ),
                h=w.alt_m,
                speed_mps=w.speed_mps,
            )
            for w in params.waypoints
        ]
        path = paths.waypoint_path(
            wps, params.speed_mps, params.turn_rate_dps, params.rate_hz, cap, params.track_altitude
        )
        return sc, path
    if params.track is not None:
        track = load_cached(params.track)
        return sc, paths.track_path(track, ref, params.rate_hz, cap, params.track_altitude)
    if params.terrain_file is not None and params.start_cell is None:
        zone = ref.zone_mask(params.stop_half_width_cells, params.stop_half_width_cells)
        length = max(80, int(params.speed_mps * 40.0 / ref.cell_m))
        start, heading = paths.informative_line(ref, zone, length, margin_cells=params.offset_max_cells)
        hd = params.heading_deg if params.heading_deg is not None else heading
        sc = sc.model_copy(update={"start_cell": start, "heading_deg": hd, "cell_m": ref.cell_m})
    elif params.terrain_file is not None:
        sc = sc.model_copy(update={"cell_m": ref.cell_m})
    return sc, None


class FlightTruth:
    """Truth of the flight for the scenario context (sensor_stats), [east, north, up] = [z, x, h].

    The straight level flight along +x is exact at any stamp; any other flight (a heading, waypoints, a track)
    is interpolated linearly between its ticks (exact at the ticks, where the sensors sample).
    """

    def __init__(self, flight: SimulatedFlight) -> None:
        self.t0 = flight.t0_s
        self.x0 = float(flight.x_true[0])
        self.z = float(flight.z_true[0])
        self.h = float(flight.h_true[0])
        self.v = flight.scenario.speed_mps
        self.flight = flight if flight.vx_true is not None else None

    def truth_at(self, stamps_ns: np.ndarray) -> TruthState:
        tau = np.asarray(stamps_ns, dtype=np.float64) / NS_PER_S - self.t0
        n = tau.size
        zeros = np.zeros(n)
        f = self.flight
        if f is None:
            pos = np.column_stack([np.full(n, self.z), self.x0 + self.v * tau, np.full(n, self.h)])
            vel = np.column_stack([np.zeros(n), np.full(n, self.v), np.zeros(n)])
            return TruthState(position_m=pos, velocity_mps=vel, heading_rad=zeros, pitch_rad=zeros, roll_rad=zeros)
        assert f.vx_true is not None and f.vz_true is not None

        def at(a: np.ndarray) -> np.ndarray:
            return np.interp(tau, f.tau, a)

        vh = at(f.vh_true) if f.vh_true is not None else zeros
        vel = np.column_stack([at(f.vz_true), at(f.vx_true), vh])
        pos = np.column_stack([at(f.z_true), at(f.x_true), at(f.h_true)])
        heading = np.mod(np.arctan2(vel[:, 0], vel[:, 1]), 2.0 * math.pi)
        return TruthState(position_m=pos, velocity_mps=vel, heading_rad=heading, pitch_rad=zeros, roll_rad=zeros)


@register(KIND)
class TerrainFlight:
    """INS, radio-altimeter and truth streams of one aircraft over a terrain map (see the module docstring)."""

    Params = TerrainFlightParams

    def __init__(self, params: TerrainFlightParams, rng: np.random.Generator, context: ScenarioContext) -> None:
        self.params = params
        self.context = context
        if params.terrain_seed is not None:
            self.terrain_seed = params.terrain_seed
        else:
            self.terrain_seed = int(child_rng(rng, "terrain").integers(0, TERRAIN_SEED_MAX))
        self.world = scenario_world(params, self.terrain_seed)
        sc, path = flight_setup(params, self.world, context.scenario)
        self.flight = simulate_flight(sc, self.world, child_rng(rng, "flight"), path)
        context.register_platform(params.platform, FlightTruth(self.flight))
        self.truth_key = keys.truth(params.platform)
        self.ins_key = keys.sensor(params.platform, INS_KIND, params.ins_id)
        self.ra_key = keys.sensor(params.platform, RADALT_KIND, params.radalt_id)

    def _truth(self, msg: Truth, header: Header) -> Truth:
        x, z, h = msg.position_m
        vx, vz, vh = msg.velocity_mps or [self.params.speed_mps, 0.0, 0.0]
        return Truth(
            header=header,
            platform=self.params.platform,
            position_m=[z, x, h],
            velocity_mps=[vz, vx, vh],
            attitude_rad=[math.atan2(vz, vx) % (2.0 * math.pi) if (vx or vz) else 0.0, 0.0, 0.0],
            extra={**msg.extra, "terrain_seed": float(self.terrain_seed)},
        )

    def events(self) -> Iterator[Event]:
        every = max(1, round(self.params.rate_hz / self.params.truth_rate_hz))
        end = self.context.duration_ns
        for msg in self.flight.messages(include_truth=True, truth_every=every):
            stamp = msg.header.stamp_ns
            if stamp > end:
                return
            header = self.context.header(stamp)
            if isinstance(msg, Truth):
                yield Event(stamp, self.truth_key, self._truth(msg, header))
            else:
                key = self.ins_key if isinstance(msg, InsSample) else self.ra_key
                yield Event(stamp, key, _with_header(msg, header))


def _with_header(msg: Message, header: Header) -> Message:
    """The message with another header, unvalidated: a NaN radio-altimeter sample goes out as a broken sensor
    would send it (the core's simulation builds it with ``model_construct``)."""
    return msg.model_copy(update={"header": header})
