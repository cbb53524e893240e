"""Property tests (Hypothesis) of the rd_nav core and the coordinator core with extreme and invalid input (issue 16).

Bad input never raises out of a handler except as ``InputRejected`` (a counted rejection), and never corrupts the
state: after every message the particle cloud, its weights, the DR error states and both covariances stay finite,
the weights sum to one, the covariances are symmetric and positive semi-definite; the coordinator's assignments name
only beacons, with epochs increasing, and it grants no departure without ``min_beacons`` other beacons.

Inputs: a valid 3-minute REF-inside stream of one moving AUV (the simulation's), then a Hypothesis-drawn list of
perturbed messages — valid-but-extreme values (the schema's limits, kilometre offsets, positions at the schema's
bound of 1e9 m), duplicates and replays of earlier messages, stamps going backwards (by 1 ns too: the ``ValueError:
DR sample at -1e-09 s precedes the last one`` of a DEPARTED after a DR sample), unknown senders and nodes — then the
rest of the stream.
"""

from __future__ import annotations

import copy
import math
from functools import lru_cache

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from schemas import AcousticArrival, Attitude, BeaconTable, Depth, Header, Message, NavPacket, SoundSpeed, SpeedLog
from schemas.acoustic import Beacon
from schemas.base import VEC_COMPONENT_MAX
from schemas.rd_nav import BeaconAssignment, VehicleStatus
from services.coordinator.config import CoordinatorConfig
from services.coordinator.core import CoordinatorCore
from services.rd_nav.config import RdNavConfig
from services.rd_nav.core import RdNavCore
from services.rd_nav.offline import node_table_message
from services.rd_nav.simulation import REF_NODES, Simulation, ref, ref_assignment
from shared.service import InputRejected

SPLIT_S = 90.0


@lru_cache(maxsize=1)
def stream() -> tuple[list[Message], list[Message]]:
    """auv4's messages of 180 s of REF inside (node table and assignment first), split at SPLIT_S."""
    scn = ref("inside", duration_s=180.0)
    sim = Simulation(scn, np.random.SeedSequence(11))
    a = ref_assignment(scn)
    sim.feed(a)
    msgs: list[Message] = [node_table_message(scn), a]
    msgs += [em.msg for em in sim.advance(180.0) if em.platform == "auv4" and em.kind != "truth"]
    t_split = scn.start_stamp_ns + round(SPLIT_S * 1e9)
    head = [m for m in msgs if m.header.stamp_ns <= t_split]
    tail = [m for m in msgs if m.header.stamp_ns > t_split]
    return head, tail


@lru_cache(maxsize=1)
def warm_core() -> RdNavCore:
    core = RdNavCore(RdNavConfig(auv_id="auv4", n_particles=200, seed=3))
    for m in stream()[0]:
        feed(core, m)
    return core


def feed(core: RdNavCore, m: Message) -> list[Message]:
    try:
        return core.step(m)
    except InputRejected:
        return []


def check_state(core: RdNavCore) -> None:
    pf = core.pf
    assert np.isfinite(pf.X).all() and np.isfinite(pf.w).all() and np.isfinite(pf.E).all() and np.isfinite(pf.PE).all()
    assert abs(float(pf.w.sum()) - 1.0) < 1e-9 and (pf.w >= 0.0).all()
    for P in (pf.estimate()[1], pf.PE, core.ekf.Pz):
        assert np.isfinite(P).all()
        assert np.allclose(P, P.T, rtol=0.0, atol=1e-9 * max(1.0, float(np.abs(P).max())))
        assert float(np.linalg.eigvalsh(0.5 * (P + P.T)).min()) >= -1e-9 * max(1.0, float(np.abs(P).max()))
    assert np.isfinite(core.ekf.z).all()


def _hdr(stamp_ns: int, frame: str = "auv4") -> Header:
    return Header(stamp_ns=max(stamp_ns, 0), frame_id=frame)


# offsets of a perturbed message's stamp from the last valid one: backwards (1 ns to an hour), equal, ahead
STAMP_OFFSETS_NS = st.one_of(
    st.sampled_from([-1, 0, 1, -1_000_000_000, 3_600_000_000_000, -3_600_000_000_000]),
    st.integers(-(10**13), 10**13),
)
#: a vector component (Vec3): up to the schema's bound, ±1e9 (beyond it a message is refused before any core)
VEC = st.one_of(
    st.floats(-VEC_COMPONENT_MAX, VEC_COMPONENT_MAX),
    st.sampled_from([0.0, -0.0, VEC_COMPONENT_MAX, -VEC_COMPONENT_MAX, 5e-324]),
)


@st.composite
def perturbation(draw: st.DrawFn, base_ns: int) -> Message:
    stamp = base_ns + draw(STAMP_OFFSETS_NS)
    head, tail = stream()
    kind = draw(st.sampled_from(["speed", "attitude", "depth", "c", "arrival", "replay", "status", "assign", "table"]))
    if kind == "speed":
        v = st.floats(-30.0, 30.0)
        return SpeedLog(
            header=_hdr(stamp),
            v_forward_mps=draw(v),
            v_starboard_mps=draw(v),
            v_down_mps=draw(v),
            bottom_lock=draw(st.booleans()),
        )
    if kind == "attitude":
        return Attitude(
            header=_hdr(stamp),
            heading_rad=draw(st.floats(-2 * math.pi, 2 * math.pi)),
            pitch_rad=draw(st.floats(-math.pi / 2, math.pi / 2)),
            roll_rad=draw(st.floats(-math.pi, math.pi)),
        )
    if kind == "depth":
        return Depth(header=_hdr(stamp), depth_m=draw(st.floats(-20.0, 11_000.0)))
    if kind == "c":
        return SoundSpeed(
            header=_hdr(stamp), c_mps=draw(st.floats(1300.0, 1800.0)), sigma_c_mps=draw(st.floats(1e-9, 100.0))
        )
    if kind in ("arrival", "replay"):
        pool = [m for m in head + tail if isinstance(m, AcousticArrival)]
        m = draw(st.sampled_from(pool))
        if kind == "replay":  # an earlier arrival again, as it was, or a duplicate of a recent one
            return m
        pk = m.packet
        pk2 = NavPacket(
            sender_id=draw(st.sampled_from([pk.sender_id, "auv1", "auv2", "auv3", "ghost"])),
            kind=draw(st.sampled_from(["LEADER", "FOLLOWER"])),
            leader_id=draw(st.sampled_from([pk.leader_id, "auv2", "ghost"])),
            cycle_seq=draw(st.integers(0, 2**16 - 1)),
            assignment_epoch=draw(st.integers(0, 5)),
            node_id=draw(st.sampled_from([pk.node_id, "n1", "n9", None])),
            pos_ned_m=[draw(VEC), draw(VEC), draw(st.floats(-1e4, 1e4))],
            pos_sigma_m=draw(st.floats(0.0, 1000.0)),
            reply_delay_s=draw(st.one_of(st.none(), st.floats(0.0, 60.0))),
        )
        return AcousticArrival(
            header=_hdr(stamp),
            receiver_id=draw(st.sampled_from(["auv4", "auv5"])),
            t_rx_local_s=draw(st.floats(0.0, 1e9)),
            packet=pk2,
        )
    if kind == "status":
        event = draw(st.sampled_from(["DEPARTED", "DOCKED", "SERVICE_DONE", "AT_BASE", "FAULT", "HEARTBEAT"]))
        pos = draw(st.one_of(st.none(), st.lists(VEC, min_size=3, max_size=3)))
        return VehicleStatus(
            header=_hdr(stamp),
            auv_id=draw(st.sampled_from(["auv4", "auv1"])),
            event=event,
            node_id=draw(st.sampled_from([None, "n1", "n2", "nowhere"])),
            position_ned_m=pos,
        )
    if kind == "assign":
        n = draw(st.integers(1, 3))
        ids = draw(
            st.lists(st.sampled_from(["auv1", "auv2", "auv3", "x"]), min_size=n + 1, max_size=n + 1, unique=True)
        )
        return BeaconAssignment(
            header=_hdr(stamp),
            epoch=draw(st.integers(0, 10)),
            leader_id=ids[0],
            follower_ids=ids[1:],
            tau_s=[draw(st.floats(0.0, 60.0)) for _ in range(n)],
            cycle_period_s=draw(st.floats(1e-3, 600.0)),
        )
    beacons = [
        Beacon(beacon_id=k, x_east_m=draw(VEC), y_north_m=draw(VEC), depth_m=draw(st.floats(-20.0, 11_000.0)))
        for k in draw(st.lists(st.sampled_from(["n1", "n2", "n3", "n4"]), min_size=1, max_size=4, unique=True))
    ]
    return BeaconTable(header=_hdr(stamp, "base_ned"), beacons=beacons)


@settings(
    max_examples=15,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(st.data())
def test_rd_nav_core_never_raises_out_and_keeps_a_valid_state(data: st.DataObject) -> None:
    core = copy.deepcopy(warm_core())
    head, tail = stream()
    base_ns = head[-1].header.stamp_ns
    for m in data.draw(st.lists(perturbation(base_ns), min_size=1, max_size=12)):
        try:
            out = core.step(m)
            assert isinstance(out, list)
        except InputRejected as exc:
            assert exc.reason  # a counted rejection with a reason code
        check_state(core)
    for m in tail[: len(tail) // 3]:  # the valid stream goes on (30 s: three cycles)
        feed(core, m)
        check_state(core)


def test_departed_one_nanosecond_before_a_dr_sample_is_a_counted_rejection() -> None:
    """The known crash: DEPARTED stamped 1 ns before the last DVL sample raised ValueError from the DR buffer."""
    core = copy.deepcopy(warm_core())
    last = max(m.header.stamp_ns for m in stream()[0] if isinstance(m, SpeedLog))
    before = core.pf.X.copy()
    msg = VehicleStatus(header=_hdr(last - 1), auv_id="auv4", event="DEPARTED", position_ned_m=[800.0, 1500.0, 80.0])
    try:
        core.step(msg)
        raised = None
    except InputRejected as exc:
        raised = exc.reason
    assert raised == "stamp_backwards"
    assert np.array_equal(core.pf.X, before)  # refused before any state change


# ------------------------------------------------------------------------------------------ coordinator ----
NODES4 = {**REF_NODES, "n4": (-1500.0, 1500.0, 100.0)}


@st.composite
def coordinator_input(draw: st.DrawFn, t_ns: int) -> Message:
    stamp = max(t_ns + draw(STAMP_OFFSETS_NS), 0)
    kind = draw(st.sampled_from(["status", "status", "status", "heard", "table"]))
    auv = draw(st.sampled_from([f"auv{k}" for k in range(1, 8)]))
    if kind == "status":
        route = draw(st.lists(st.lists(VEC, min_size=3, max_size=3), max_size=4))
        return VehicleStatus(
            header=_hdr(stamp, "base_ned"),
            auv_id=auv,
            event=draw(st.sampled_from(["DOCKED", "SERVICE_DONE", "AT_BASE", "DEPARTED", "FAULT", "HEARTBEAT"])),
            node_id=draw(st.sampled_from(["n1", "n2", "n3", "n4", "nowhere", None])),
            position_ned_m=draw(st.one_of(st.none(), st.lists(VEC, min_size=3, max_size=3))),
            planned_route_ned_m=route,
            speed_mps=draw(st.one_of(st.none(), st.floats(0.0, 10.0))),
        )
    if kind == "heard":
        pk = NavPacket(
            sender_id=auv,
            kind="LEADER",
            leader_id=auv,
            cycle_seq=draw(st.integers(0, 2**16 - 1)),
            assignment_epoch=draw(st.integers(0, 20)),
            pos_ned_m=[0.0, 0.0, 100.0],
            pos_sigma_m=0.0,
        )
        return AcousticArrival(header=_hdr(stamp, "base"), receiver_id="base", t_rx_local_s=1.0, packet=pk)
    node = draw(st.sampled_from(["n1", "n2", "n3", "n4"]))
    return BeaconTable(
        header=_hdr(stamp, "base_ned"),
        beacons=[Beacon(beacon_id=node, x_east_m=draw(VEC), y_north_m=draw(VEC), depth_m=100.0)],
    )


@settings(max_examples=30, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(st.data(), st.sampled_from(["full", "arrival_time"]))
def test_coordinator_never_raises_out_and_keeps_its_invariants(data: st.DataObject, cost_model: str) -> None:
    co = CoordinatorCore(CoordinatorConfig(node_table_ned_m=NODES4, cost_model=cost_model))  # type: ignore[arg-type]
    epochs: list[int] = []
    t_ns = 1_000_000_000
    for _ in range(data.draw(st.integers(1, 40))):
        m = data.draw(coordinator_input(t_ns))
        t_ns = max(t_ns, m.header.stamp_ns)
        try:
            out = co.step(m)
        except InputRejected as exc:
            assert exc.reason
            continue
        beacons = co.beacons()
        for o in out:
            if isinstance(o, BeaconAssignment):
                epochs.append(o.epoch)
                members = [o.leader_id, *o.follower_ids]
                assert len(set(members)) == len(members)
                assert set(members) <= set(beacons) | {a for a, r in co.vehicles.items() if r.state == "GRANTED"}
            elif hasattr(o, "auv_id") and type(o).__name__ == "DepartureGrant":
                others = [k for k in beacons if k != o.auv_id]
                assert len(others) >= co.cfg.min_beacons
    assert epochs == sorted(epochs) and len(set(epochs)) == len(epochs)
