"""Player plugin ``rd_group``: a group of AUVs navigating by RD-LBL, closed through the base coordinator (digest 002).

Wraps the pure :class:`~services.rd_nav.simulation.Simulation` (sensor-node field; AUVs transiting, docking,
servicing and leaving; the leader broadcast and follower replies through the acoustic channel model; DVL,
attitude, depth and sound-speed sensors). The group **obeys the coordinator's decisions**: it is an interactive
simulator (:class:`~services.player.simulators.InteractiveSimulator`). The run advances in steps of
``exchange_period_s``; what the vehicles send to the base station during a step (their ``VehicleStatus``
reports, the beacons' packets heard at the base, the node table at t = 0) are *requests*; once the step is
published the simulation waits for the coordinator's ``CoordinatorReply`` to each and applies the decisions at
the end of the step: a ``BeaconAssignment`` changes the beacons' roles from their next cycle and is received by
every vehicle; a ``DepartureGrant`` makes a beacon stop transmitting and undock ``undock_delay_s`` later.

Two drivers, one generator (:meth:`RdGroup.interact`): ``fixstream play`` waits for the coordinator *service*'s
replies on Zenoh (``fixstream/group/<group>/reply``, :mod:`services.player.exchange`); ``events()``
(``fixstream mc``, ``scenario_events``) asks a :class:`~services.coordinator.protocol.CoordinatorProtocol`
in-process. The coordinator being deterministic, both give the same event stream for the same seed, provided the
service runs the configuration of ``coordinator_config`` (a reply carries its configuration's digest; a
different one is logged). With ``coordinator: false`` the group keeps a fixed assignment (``fixed_assignment``,
default the digest's REF set) and nothing is exchanged.

Keys (``<g>`` = ``group``, ``<v>`` = a vehicle id):

* ``fixstream/sensor/<v>/dvl/dvl0`` ``SpeedLog``, ``.../attitude/ahrs0`` ``Attitude``, ``.../depth/press0``
  ``Depth``, ``.../sound_speed/svs0`` ``SoundSpeed`` (moving vehicles), ``.../acoustic/modem0`` ``AcousticArrival``
  (packets a moving vehicle receives, on its own clock), ``.../nav/status`` ``VehicleStatus`` (the vehicle's own
  mission events), ``.../nav/nodes`` ``BeaconTable`` (t = 0), ``.../nav/assignment`` ``BeaconAssignment`` (as
  received from the base) — everything an ``rd_nav`` instance of that vehicle needs, under one prefix;
* ``fixstream/group/<g>/uplink/<v>/status`` ``VehicleStatus``, ``.../uplink/base/acoustic`` ``AcousticArrival``
  heard at the base, ``.../uplink/base/nodes`` ``BeaconTable``: the coordinator's inputs (the requests);
* ``fixstream/truth/<v>`` ``Truth`` every ``truth_period_s`` and, for a moving vehicle, at the stamp of each
  leader packet it receives (the epoch of its cycle fixes): ``position_m`` ``[east, north, up]`` in the scenario
  frame (the base-station frame: east = NED y, north = NED x, up = -depth), velocity, ``attitude_rad``
  ``[heading, 0, 0]``; ``extra``: ``depth_m``, ``moving`` (1/0).

A mover may fly a recorded trajectory file instead of a path (``vehicles[].track``,
:class:`~services.player.simulators.recorded_track.TrackFileParams`; docs/scenarios.md, "Trajectory files"): the
track's east/north/up in the scenario frame from t = 0, its depth (-up) for the depth sensor and the acoustic
ranges, its heading (recorded, else the course) and horizontal speed for the DVL and attitude sensors. The run
then ends with the shortest track (its last row), the docked beacons staying where they are.

Stamps: the data clock of the simulation = scenario time (ns since the start). Messages carry the simulation's
frame ids (``base_ned`` for positions in NED, ``<v>/body`` for body-frame sensors); the ``Truth`` the scenario's.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, Field, ValidationError, model_validator

from schemas import BeaconTable, Header, Message
from schemas.acoustic import Beacon
from schemas.rd_nav import BeaconAssignment, CoordinatorReply, DepartureGrant
from services.coordinator.config import CoordinatorConfig
from services.coordinator.protocol import CoordinatorProtocol, config_digest
from services.coordinator.service import reply_key, uplink_key
from services.player.simulators import Event, Exchange, ExchangeSpec, ScenarioContext, SimParams, register
from services.player.simulators.recorded_track import TrackFileParams, load_cached
from shared import keys

from .simulation import REF_BEACONS, REF_MOVER, REF_NODES, Emitted, ScenarioConfig, Simulation, VehicleSpec, fleet

log = logging.getLogger("fixstream.rd_group")

#: (kind, sensor id) of the sensor keys fixstream/sensor/<v>/<kind>/<id> per Simulation output kind
SENSOR_KEYS: dict[str, tuple[str, str]] = {
    "dvl": ("dvl", "dvl0"),
    "attitude": ("attitude", "ahrs0"),
    "depth": ("depth", "press0"),
    "sound_speed": ("sound_speed", "svs0"),
    "acoustic": ("acoustic", "modem0"),
}
#: the sender chunk of the base station's own uplink keys (a vehicle may not be called so)
BASE = "base"
PathName = Literal["inside", "boundary", "outside", "racetrack"]


def _chunk(v: str) -> str:
    keys.chunk(v)
    if v == BASE:
        raise ValueError(f"{BASE!r} names the base station's uplink; choose another vehicle id")
    return v


VehicleId = Annotated[str, AfterValidator(_chunk)]
Pair = Annotated[list[float], Field(min_length=2, max_length=2)]
Triple = Annotated[list[float], Field(min_length=3, max_length=3)]


def nav_key(auv_id: str, item: str) -> str:
    """``fixstream/sensor/<v>/nav/<item>`` (item: status, nodes, assignment)."""
    return keys.sensor(auv_id, "nav", item)


def sensor_key(auv_id: str, kind: str) -> str:
    """The sensor key of a Simulation output kind (dvl, attitude, depth, sound_speed, acoustic)."""
    k, sid = SENSOR_KEYS[kind]
    return keys.sensor(auv_id, k, sid)


class VehicleParams(SimParams):
    """One AUV of the group."""

    id: VehicleId = Field(description="vehicle id: its keys and the rd_nav instance that navigates it")
    node: str | None = Field(default=None, description="node it is docked at when the run starts (None: moving)")
    path: PathName | list[Pair] | None = Field(
        default=None, description="a mover's fixed path: a REF trajectory, or waypoints [north, east], m"
    )
    route: list[str] = Field(default_factory=list, max_length=256, description="nodes to visit in order (cyclic)")
    service_s: float | None = Field(default=None, gt=0.0, description="servicing time at a node, s (None: never)")
    speeds_mps: list[Annotated[float, Field(gt=0.0, le=10.0)]] | None = Field(
        default=None, max_length=4096, description="speed on each leg of a waypoint path, m/s (None: speed_mps)"
    )
    hold_s: list[Annotated[float, Field(ge=0.0)]] | None = Field(
        default=None, max_length=4096, description="hover time at each waypoint (the first: before leaving), s"
    )
    repeat: bool = Field(default=False, description="a waypoint path starts over at its end")
    track: TrackFileParams | None = Field(
        default=None, description="a mover's recorded trajectory instead of a path (from t = 0; the run ends with it)"
    )

    @model_validator(mode="after")
    def _where(self) -> VehicleParams:
        if sum(x is not None for x in (self.node, self.path, self.track)) != 1:
            raise ValueError("give exactly one of node (docked at the start), path or track (moving at the start)")
        if self.track is not None:
            if self.route or self.service_s is not None or self.speeds_mps is not None or self.hold_s is not None:
                raise ValueError("a recorded track is the whole motion: no route, service_s, speeds_mps or hold_s")
            if self.repeat:
                raise ValueError("a recorded track is not repeated")
            if self.track.time_offset_s != 0.0:
                raise ValueError("track.time_offset_s: a mover moves from t = 0 (the track's first row)")
            load_cached(self.track)  # a missing or malformed file is a parameter error
        if isinstance(self.path, list) and len(self.path) < 2:
            raise ValueError("a waypoint path needs at least two points")
        profiled = self.speeds_mps is not None or self.hold_s is not None or self.repeat
        if profiled and not isinstance(self.path, list):
            raise ValueError("speeds_mps, hold_s and repeat need a waypoint path")
        if isinstance(self.path, list):
            legs = len(self.path) - 1
            if self.speeds_mps is not None and len(self.speeds_mps) != legs:
                raise ValueError(f"speeds_mps: one speed per leg ({legs})")
            if self.hold_s is not None and len(self.hold_s) != legs + 1:
                raise ValueError(f"hold_s: one hover time per waypoint ({legs + 1})")
            if self.repeat and (self.path[0][0], self.path[0][1]) != (self.path[-1][0], self.path[-1][1]):
                raise ValueError("a repeated path must end where it starts")
        return self


class FixedAssignment(SimParams):
    """The beacon set of an open-loop run (``coordinator: false``)."""

    leader: VehicleId
    followers: list[VehicleId] = Field(min_length=1, max_length=16, description="reply-slot order")
    tau_s: list[Annotated[float, Field(ge=0.0, le=60.0)]] | None = Field(
        default=None, description="reply delays, s (None: tau_s of the simulation)"
    )


class RdGroupParams(SimParams):
    """Parameters of ``rd_group``. Every ``None`` takes the preset's value (``preset`` REF/LOW: digest §5.4)."""

    group: Annotated[str, AfterValidator(keys.chunk)] = Field(
        default="group1", description="group id: the coordinator instance and the keys fixstream/group/<group>/..."
    )
    preset: Literal["ref", "low", "fleet", "custom"] = Field(
        default="ref",
        description="ref/low: the digest's triangle (auv1-3 docked at n1-n3, auv4 on `path`), LOW noise for low; "
        "fleet: six AUVs on a hexagon of nodes, one at the base, two servicing; custom: give nodes and vehicles",
    )
    path: PathName = Field(default="inside", description="the REF/LOW mover's trajectory (§5.4, T-ROB-12)")
    nodes: dict[str, Triple] | None = Field(
        default=None, description="surveyed node id -> [north, east, depth], m (base docks 'base/<vehicle>')"
    )
    vehicles: list[VehicleParams] | None = Field(default=None, max_length=64)
    # --- the closed loop ---
    coordinator: bool = Field(default=True, description="obey the coordinator's replies (False: fixed_assignment)")
    coordinator_config: dict[str, Any] = Field(
        default_factory=dict, description="CoordinatorConfig fields of the in-process twin (= the service's env)"
    )
    exchange_period_s: float = Field(default=1.0, gt=0.0, le=60.0, description="decision step, s")
    exchange_timeout_s: float = Field(default=10.0, gt=0.0, le=600.0, description="wall time to wait for replies, s")
    fixed_assignment: FixedAssignment | None = Field(default=None, description="open loop; None: REF set")
    # --- truth ---
    truth_period_s: float = Field(default=1.0, ge=0.0, description="periodic Truth of every vehicle, s (0: none)")
    truth_at_leader_arrivals: bool = Field(default=True, description="Truth of a mover at each leader arrival")
    # --- motion and protocol (None: the preset's) ---
    speed_mps: float | None = Field(default=None, gt=0.0, le=10.0, description="transit speed, m/s")
    auv_depth_m: float | None = Field(default=None, ge=0.0, le=11_000.0, description="transit depth, m")
    cycle_period_s: float | None = Field(default=None, gt=0.0, le=600.0, description="leader period T_c, s")
    cycle_phase_s: float | None = Field(default=None, ge=0.0, description="first leader emission, s")
    emit_jitter_s: float | None = Field(default=None, ge=0.0, description="uniform leader emission jitter, s")
    tau_s: list[Annotated[float, Field(ge=0.0, le=60.0)]] | None = Field(default=None, description="reply slots, s")
    undock_delay_s: float | None = Field(default=None, ge=0.0, description="grant -> DEPARTED, s")
    heartbeat_period_s: float | None = Field(default=None, ge=0.0, description="HEARTBEAT reports, s (0: none)")
    base_position_ned_m: Triple | None = Field(default=None, description="the base listener, [north, east, depth]")
    # --- acoustic channel and clocks ---
    c_true_mps: float | None = Field(default=None, ge=1300.0, le=1800.0, description="true sound speed, m/s")
    sigma_t_s: float | None = Field(default=None, ge=0.0, description="arrival-time noise per arrival, s")
    sigma_f_s: float | None = Field(default=None, ge=0.0, description="follower detection jitter, s")
    follower_skew_ppm: float | None = Field(default=None, description="follower clock skew, ppm")
    clock_offset_max_s: float | None = Field(default=None, ge=0.0, description="receiver clock offsets in [1, 1+x], s")
    clock_skew_ppm: float | None = Field(default=None, description="receiver clock skew, ppm")
    clock_steps: list[Pair] | None = Field(default=None, description="receiver clock steps [true time, step], s")
    stamp_jitter_s: float | None = Field(default=None, ge=0.0, description="data-clock stamp jitter of arrivals, s")
    packet_loss: float | None = Field(default=None, ge=0.0, le=1.0, description="per packet and receiver")
    loss_at_followers: bool | None = Field(default=None, description="followers can miss the leader packet too")
    multipath_prob: float | None = Field(default=None, ge=0.0, le=1.0, description="late arrival probability")
    multipath_delay_s: Pair | None = Field(default=None, description="[low, high] uniform late-arrival delay, s")
    blackouts: list[Pair] | None = Field(default=None, description="[t0, t1] no reception, s")
    node_error_sigma_m: float | None = Field(default=None, ge=0.0, description="true - surveyed node, per axis, m")
    # --- on-board sound speed ---
    sigma_c_est_mps: float | None = Field(default=None, ge=0.0, description="white error per cycle, m/s")
    c_bias_mps: float | None = Field(default=None, description="constant error, m/s")
    sigma_c_reported_mps: float | None = Field(default=None, gt=0.0, description="sigma in SoundSpeed, m/s")
    # --- DR sensors (§5.4) ---
    sensor_period_s: float | None = Field(default=None, gt=0.0, description="DVL/attitude period, s")
    speed_gm_sigma_mps: float | None = Field(default=None, ge=0.0, description="speed Gauss-Markov sigma, m/s")
    speed_gm_tau_s: float | None = Field(default=None, gt=0.0, description="its correlation time, s")
    speed_white_mps: float | None = Field(default=None, ge=0.0, description="white speed noise, m/s")
    speed_scale_gm_sigma: float | None = Field(
        default=None, ge=0.0, le=0.5, description="speed scale-factor Gauss-Markov sigma (fraction of the speed)"
    )
    speed_scale_gm_tau_s: float | None = Field(default=None, gt=0.0, description="its correlation time, s")
    heading_gm_sigma_deg: float | None = Field(default=None, ge=0.0, description="heading Gauss-Markov sigma, deg")
    heading_gm_tau_s: float | None = Field(default=None, gt=0.0, description="its correlation time, s")
    heading_white_deg: float | None = Field(default=None, ge=0.0, description="white heading noise, deg")
    dvl_dropouts: list[Pair] | None = Field(default=None, description="[t0, t1] no bottom lock, s")
    depth_period_s: float | None = Field(default=None, gt=0.0, description="depth sensor period, s")
    depth_sigma_m: float | None = Field(default=None, ge=0.0, description="depth noise, m")

    @model_validator(mode="after")
    def _check(self) -> RdGroupParams:
        if self.preset == "custom" and (self.nodes is None or self.vehicles is None):
            raise ValueError("preset custom needs nodes and vehicles")
        try:
            CoordinatorConfig.model_validate(self.coordinator_config)
        except ValidationError as exc:
            first = exc.errors()[0]
            raise ValueError(f"coordinator_config.{'.'.join(str(p) for p in first['loc'])}: {first['msg']}") from None
        cfg = self.scenario_config(1.0)
        ids = [v.auv_id for v in cfg.vehicles]
        if len(set(ids)) != len(ids):
            raise ValueError("vehicle ids must be unique")
        for v in cfg.vehicles:
            for node in [v.start_node, *v.route]:
                if node is not None and node not in cfg.nodes:
                    raise ValueError(f"vehicle {v.auv_id}: node {node!r} is not in nodes")
        if not self.coordinator:
            fa = self.assignment_spec()
            members = [fa.leader, *fa.followers]
            for m in members:
                if m not in ids:
                    raise ValueError(f"fixed_assignment: {m} is not a vehicle")
            if len(set(members)) != len(members):
                raise ValueError("fixed_assignment: leader and followers must be distinct")
        return self

    def end_s(self, duration_s: float) -> float:
        """The run's end (s): ``duration_s``, or the last row of the shortest recorded track if earlier."""
        ends = [load_cached(v.track).end_s for v in self.vehicles or [] if v.track is not None]
        return min([duration_s, *ends])

    def assignment_spec(self) -> FixedAssignment:
        if self.fixed_assignment is not None:
            return self.fixed_assignment
        return FixedAssignment(leader="auv1", followers=["auv2", "auv3"])

    def scenario_config(self, duration_s: float) -> ScenarioConfig:
        """The simulation's configuration: the preset, then every parameter given here."""
        if self.preset == "fleet":
            base = fleet().model_dump()
        else:
            base = ScenarioConfig().model_dump()
            base["vehicles"] = [
                *(VehicleSpec(auv_id=a, start_node=n).model_dump() for a, n in REF_BEACONS.items()),
                VehicleSpec(auv_id=REF_MOVER, path=self.path).model_dump(),
            ]
            base["nodes"] = dict(REF_NODES)
            if self.preset == "low":
                base.update(sigma_t_s=0.1e-3, sigma_c_est_mps=0.1)
        if self.nodes is not None:
            base["nodes"] = {k: tuple(v) for k, v in self.nodes.items()}
        if self.vehicles is not None:
            base["vehicles"] = [
                VehicleSpec(
                    auv_id=v.id,
                    start_node=v.node,
                    path=v.path if isinstance(v.path, str) or v.path is None else [(p[0], p[1]) for p in v.path],
                    route=list(v.route),
                    service_s=v.service_s,
                    speeds_mps=v.speeds_mps,
                    hold_s=v.hold_s,
                    repeat=v.repeat,
                    track=v.track,
                )
                for v in self.vehicles
            ]
        skip = {"group", "preset", "path", "nodes", "vehicles", "coordinator", "coordinator_config"}
        skip |= {"exchange_period_s", "exchange_timeout_s", "fixed_assignment", "truth_period_s"}
        skip |= {"truth_at_leader_arrivals"}
        for name in type(self).model_fields:
            value = getattr(self, name)
            if name in skip or value is None:
                continue
            if isinstance(value, list) and value and isinstance(value[0], list):
                value = [tuple(x) for x in value]
            elif name in ("multipath_delay_s", "base_position_ned_m"):
                value = tuple(value)
            base[name] = value
        base.update(
            name=self.preset,
            duration_s=duration_s,
            start_stamp_ns=0,
            base_listener=self.coordinator,
            truth_period_s=self.truth_period_s,
            truth_at_leader_arrivals=self.truth_at_leader_arrivals,
            truth_axes="enu",
        )
        return ScenarioConfig.model_validate(base)


@register("rd_group")
class RdGroup:
    """The simulated group and its acoustic channel; see the module docstring."""

    Params = RdGroupParams

    def __init__(self, params: RdGroupParams, rng: np.random.Generator, context: ScenarioContext) -> None:
        self.params = params
        self.context = context
        seq = rng.bit_generator.seed_seq
        if not isinstance(seq, np.random.SeedSequence):
            raise TypeError("rd_group needs a Generator built from a numpy SeedSequence")
        self._seed = (seq.entropy, seq.spawn_key)
        #: the run's end, s: the scenario's, or the end of the shortest recorded track
        self.end_s = params.end_s(context.duration_s)
        self.cfg = params.scenario_config(self.end_s)
        self.cfg = self.cfg.model_copy(update={"truth_frame_id": context.frame_id})
        self.group = params.group
        self.coordinator_config = CoordinatorConfig.model_validate(params.coordinator_config)
        self.digest = config_digest(self.coordinator_config)
        self.vehicle_ids = [v.auv_id for v in self.cfg.vehicles]
        #: the last run's simulation (for tests: protocol violations, grants)
        self.sim: Simulation | None = None
        self.digest_mismatch = False
        self._keys: dict[tuple[str, str], str] = {}

    # ----- InteractiveSimulator ------------------------------------------------------------------------------
    def exchange_spec(self) -> ExchangeSpec | None:
        if not self.params.coordinator:
            return None
        return ExchangeSpec(reply_key(self.group), _answers, self.params.exchange_timeout_s)

    def events(self) -> Iterator[Event]:
        """The closed loop with the coordinator in-process (or the open loop)."""
        return self.interact(self.local_exchange())

    def local_exchange(self) -> Exchange:
        """The in-process twin of the coordinator service: a CoordinatorProtocol with ``coordinator_config``."""
        return LocalCoordinator(self.group, self.coordinator_config)

    def interact(self, exchange: Exchange) -> Iterator[Event]:
        """Step by step: publish a step's events, ask ``exchange`` for the replies to its requests, apply them."""
        p = self.params
        sim = Simulation(self.cfg, np.random.SeedSequence(entropy=self._seed[0], spawn_key=self._seed[1]))
        self.sim = sim
        first = self._initial_events(sim)
        if not p.coordinator:
            a = self._fixed_assignment(sim)
            sim.feed(a)
            first += self._downlink(a, 0)
        pending = first
        end = self.end_s
        k = 0
        while True:
            t = min(k * p.exchange_period_s, end)
            requests: list[Event] = []
            chunk = pending + self._map(sim.advance(t), requests)
            if k == 0:
                requests = [ev for ev in first if ev.key.startswith(f"{keys.ROOT}/group/")] + requests
            pending = []
            yield from chunk
            if t >= end:
                return
            if requests and p.coordinator:
                pending = self._apply(sim, exchange(requests), sim.stamp_ns(t))
            k += 1

    # ----- internals -----------------------------------------------------------------------------------------
    def _initial_events(self, sim: Simulation) -> list[Event]:
        """At t = 0: the node table for the coordinator (a request) and for every vehicle's navigation."""
        table = BeaconTable(
            header=Header(stamp_ns=0, frame_id="base_ned"),
            beacons=[
                Beacon(beacon_id=k, x_east_m=float(v[1]), y_north_m=float(v[0]), depth_m=float(v[2]))
                for k, v in self.cfg.nodes.items()
            ],
        )
        out: list[Event] = []
        if self.params.coordinator:
            out.append(Event(0, uplink_key(self.group, BASE, "nodes"), table))
        out += [Event(0, nav_key(v, "nodes"), table) for v in self.vehicle_ids]
        return out

    def _fixed_assignment(self, sim: Simulation) -> BeaconAssignment:
        fa = self.params.assignment_spec()
        members = [fa.leader, *fa.followers]
        nodes = [sim.vehicles[m].node_id for m in members]
        tau = fa.tau_s if fa.tau_s is not None else list(self.cfg.tau_s[: len(fa.followers)])
        if len(tau) != len(fa.followers):
            raise ValueError("fixed_assignment: one tau_s per follower")
        return BeaconAssignment(
            header=Header(stamp_ns=0, frame_id="base_ned"),
            epoch=1,
            leader_id=fa.leader,
            follower_ids=list(fa.followers),
            tau_s=list(tau),
            cycle_period_s=self.cfg.cycle_period_s,
            positions_ned_m=[list(self.cfg.nodes[n]) if n is not None else [0.0, 0.0, 0.0] for n in nodes],
            reason="fixed",
        )

    def _key(self, platform: str, kind: str) -> str:
        """The key of a Simulation output (memoised: key building validates every chunk)."""
        key = self._keys.get((platform, kind))
        if key is None:
            if kind == "truth":
                key = keys.truth(platform)
            elif kind == "uplink_status":
                key = uplink_key(self.group, platform, "status")
            elif kind == "status":
                key = nav_key(platform, "status")
            elif platform == BASE:
                key = uplink_key(self.group, BASE, "acoustic")
            else:
                key = sensor_key(platform, kind)
            self._keys[(platform, kind)] = key
        return key

    def _map(self, emitted: list[Emitted], requests: list[Event]) -> list[Event]:
        """Simulation outputs -> events on their keys; the coordinator's inputs also go to ``requests``."""
        out: list[Event] = []
        coord = self.params.coordinator
        for em in emitted:
            msg = em.msg
            stamp = msg.header.stamp_ns
            if em.kind == "status":
                if coord:
                    ev = Event(stamp, self._key(em.platform, "uplink_status"), msg)
                    out.append(ev)
                    requests.append(ev)
                out.append(Event(stamp, self._key(em.platform, "status"), msg))
            elif em.platform == BASE:
                if coord:  # a packet heard at the base station
                    ev = Event(stamp, self._key(BASE, em.kind), msg)
                    out.append(ev)
                    requests.append(ev)
            else:
                out.append(Event(stamp, self._key(em.platform, em.kind), msg))
        return out

    def _apply(self, sim: Simulation, replies: list[Message], stamp_ns: int) -> list[Event]:
        """Feed the decisions of the replies (in order: a reply's assignments, then its grants, as the coordinator
        makes them) into the simulation; the assignments are received by every vehicle at ``stamp_ns``."""
        down: list[Event] = []
        for r in replies:
            if not isinstance(r, CoordinatorReply):
                continue
            if r.config_digest and r.config_digest != self.digest and not self.digest_mismatch:
                self.digest_mismatch = True
                log.warning(
                    "%s: the coordinator runs configuration %s, the scenario's in-process twin %s: the run will differ "
                    "from fixstream mc and scenario_events",
                    self.group,
                    r.config_digest,
                    self.digest,
                )
            decisions: list[BeaconAssignment | DepartureGrant] = [*r.assignments, *r.grants]
            for d in decisions:
                sim.feed(d)
                if isinstance(d, BeaconAssignment):
                    down += self._downlink(d, stamp_ns)
        return down

    def _downlink(self, a: BeaconAssignment, stamp_ns: int) -> list[Event]:
        """The assignment as every vehicle's navigation receives it (stamped when received)."""
        received = a.model_copy(update={"header": Header(stamp_ns=stamp_ns, frame_id=a.header.frame_id)})
        return [Event(stamp_ns, nav_key(v, "assignment"), received) for v in self.vehicle_ids]


def _answers(msg: Message) -> tuple[str, str, int] | None:
    """The request a coordinator reply answers: (source, key, seq)."""
    if isinstance(msg, CoordinatorReply):
        return msg.input_source, msg.input_key, msg.input_seq
    return None


class LocalCoordinator:
    """An exchange answered in-process by a :class:`CoordinatorProtocol` (the offline driver)."""

    def __init__(self, group: str, config: CoordinatorConfig) -> None:
        self.protocol = CoordinatorProtocol(group, config)

    def __call__(self, requests: list[Event]) -> list[Message]:
        return [self.protocol.handle(ev.key, ev.msg).reply for ev in requests]


__all__ = [
    "BASE",
    "SENSOR_KEYS",
    "FixedAssignment",
    "LocalCoordinator",
    "RdGroup",
    "RdGroupParams",
    "VehicleParams",
    "nav_key",
    "sensor_key",
]
