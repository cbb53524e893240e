"""The player plugin ``rd_group`` (issue 5): parameters, keys and conventions, the closed loop's two drivers, and
every ``scenarios/rd_*.yaml``.

The closed loop is tested without Zenoh here: ``events()`` (the coordinator's in-process twin) must equal
``interact()`` driven by the coordinator *service* (its ``process`` path, bytes and all), and an exchange that stops
answering must leave the group with its last assignment. Over a real router: ``test_rd_nav_e2e.py``.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np
import pytest
from conftest import REPO
from test_rd_nav_service import demo

from schemas import AcousticArrival, BeaconTable, Message, SpeedLog, Truth
from schemas.rd_nav import BeaconAssignment, CoordinatorReply, VehicleStatus
from services.coordinator.service import CoordinatorService, CoordinatorSettings, reply_key, uplink_key
from services.player.scenario import Scenario, ScenarioError, load_scenario, parse_scenario
from services.player.sensor_stats import sensor_stats
from services.player.simulators import Event, InteractiveSimulator, is_interactive
from services.player.timeline import build, scenario_events, stamp
from services.rd_nav.simulator import RdGroup, nav_key, sensor_key
from shared import codec, keys

SCENARIOS = sorted((REPO / "scenarios").glob("rd_*.yaml"))


def scenario(params: dict[str, Any], duration_s: float = 120.0, seed: int = 3) -> Scenario:
    return parse_scenario(
        {
            "name": "rd_test",
            "seed": seed,
            "duration_s": duration_s,
            "simulators": [{"kind": "rd_group", "id": "group1", "params": params}],
        }
    )


def plugin(sc: Scenario, seed: int | None = None) -> RdGroup:
    sim = build(sc, sc.seed if seed is None else seed)
    (_, s) = sim.simulators[0]
    assert isinstance(s, RdGroup)
    return s


# ------------------------------------------------------------------------------------------------ parameters ----
@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"preset": "custom"}, "preset custom needs nodes and vehicles"),
        ({"vehicles": [{"id": "base", "node": "n1"}]}, "names the base station"),
        ({"vehicles": [{"id": "auv1", "node": "n1", "path": "inside"}]}, "exactly one of node"),
        ({"vehicles": [{"id": "auv1", "node": "n7"}]}, "node 'n7' is not in nodes"),
        ({"vehicles": [{"id": "auv1", "node": "n1", "route": ["n2", "n8"]}]}, "node 'n8' is not in nodes"),
        ({"coordinator_config": {"min_beacons": 1}}, "coordinator_config.min_beacons"),
        (
            {"coordinator": False, "fixed_assignment": {"leader": "auv1", "followers": ["auv9"]}},
            "auv9 is not a vehicle",
        ),
        ({"packet_loss": 1.5}, "packet_loss"),
        ({"multipath_delay_s": [0.1]}, "multipath_delay_s"),
        ({"sigma_t": 0.1}, "sigma_t"),
    ],
)
def test_parameters_are_checked(params: dict[str, Any], message: str) -> None:
    with pytest.raises(ScenarioError, match=message):
        scenario(params)


def test_presets_and_overrides_reach_the_simulation() -> None:
    ref = plugin(scenario({"preset": "ref", "path": "outside"}, 14400.0)).cfg
    assert ref.sigma_t_s == 0.2e-3 and ref.sigma_c_est_mps == 0.3 and ref.duration_s == 14400.0
    assert [v.auv_id for v in ref.vehicles] == ["auv1", "auv2", "auv3", "auv4"] and ref.vehicles[3].path == "outside"
    assert ref.start_stamp_ns == 0 and ref.base_listener and ref.truth_axes == "enu"
    low = plugin(scenario({"preset": "low", "clock_steps": [[7202.0, 0.5]], "multipath_delay_s": [0.002, 0.05]})).cfg
    assert low.sigma_t_s == 0.1e-3 and low.sigma_c_est_mps == 0.1
    assert low.clock_steps == [(7202.0, 0.5)] and low.multipath_delay_s == (0.002, 0.05)
    fleet = plugin(
        scenario(
            {
                "preset": "fleet",
                "coordinator": False,
                "fixed_assignment": {"leader": "auv2", "followers": ["auv4", "auv5"]},
            }
        )
    ).cfg
    assert len(fleet.vehicles) == 7 and not fleet.base_listener


# ------------------------------------------------------------------------------------------------ keys ----------
def test_keys_truth_and_conventions_of_the_demo() -> None:
    sc, events = demo()
    counts = Counter(e.key for e in events)
    g = "fixstream/group/group1/uplink"
    vehicles = ["auv1", "auv2", "auv3", "auv4", "auv5"]
    for v in vehicles:
        assert counts[nav_key(v, "nodes")] == 1 and counts[f"{g}/{v}/status"] >= 1
        assert counts[nav_key(v, "assignment")] == 3  # every vehicle receives every assignment
        assert counts[keys.truth(v)] >= 121  # 1 Hz, plus a mover's truth at its leader arrivals
    assert counts[f"{g}/base/nodes"] == 1 and counts[f"{g}/base/acoustic"] > 0
    movers = {k.split("/")[2] for k in counts if "/dvl/" in k}
    assert movers == {"auv3", "auv4"}
    assert counts[sensor_key("auv4", "dvl")] == 121 and counts[sensor_key("auv4", "sound_speed")] == 13
    for k in counts:
        assert k.startswith(("fixstream/sensor/", "fixstream/truth/", f"{g}/")), k
    # Truth: [east, north, up] in the scenario frame, exactly at every leader arrival of a mover
    truth = {e.stamp_ns: e.msg for e in events if e.key == keys.truth("auv4")}
    leaders = [e for e in events if e.key == sensor_key("auv4", "acoustic") and e.msg.packet.kind == "LEADER"]  # type: ignore[attr-defined]
    assert leaders and all(e.stamp_ns in truth for e in leaders)
    t0 = truth[0]
    assert isinstance(t0, Truth) and t0.header.frame_id == sc.frame_id == "local_enu"
    assert t0.position_m == pytest.approx([500.0, -1000.0, -80.0]) and t0.velocity_mps == pytest.approx([1.5, 0.0, 0.0])
    assert t0.attitude_rad == pytest.approx([math.pi / 2, 0.0, 0.0]) and t0.extra == {"depth_m": 80.0, "moving": 1.0}
    docked = next(e.msg for e in events if e.key == keys.truth("auv1"))
    assert isinstance(docked, Truth) and docked.position_m == pytest.approx([1500.0, 2481.935, -100.0])
    # the sensors against that truth (the player's built-in sensor statistics): the DR error model of §5.4
    stats = sensor_stats(events)
    dvl = stats[sensor_key("auv4", "dvl")]["errors"]["v_forward_mps"]
    assert dvl["count"] == 121 and dvl["rms"] < 0.2
    assert stats[sensor_key("auv4", "attitude")]["errors"]["heading_rad"]["rms"] < math.radians(8.0)
    assert stats[sensor_key("auv4", "depth")]["errors"]["depth_m"]["rms"] < 1e-9


def test_deterministic_by_seed() -> None:
    sc = load_scenario(REPO / "scenarios" / "rd_demo.yaml")
    a = scenario_events(sc, 5)
    assert a == scenario_events(sc, 5)
    b = scenario_events(sc, 6)
    assert [e.key for e in a][:20] == [e.key for e in b][:20] and a != b


# ------------------------------------------------------------------------------------------------ closed loop ---
class ServiceExchange:
    """An exchange answered by the coordinator *service* through its full input path (encode, decode, core,
    reply), as over Zenoh but in-process: the player's stamping (source, per-key seq) is applied first."""

    def __init__(self) -> None:
        self.svc = CoordinatorService(CoordinatorSettings(instance="group1"))
        self.svc.run_offline([])
        self.seq: Counter[str] = Counter()
        self.calls = 0

    def __call__(self, requests: list[Event]) -> list[Message]:
        self.calls += 1
        start = len(self.svc.outbox)
        for ev in requests:
            header = ev.msg.header.model_copy(update={"source": "player/default", "seq": self.seq[ev.key]})
            self.seq[ev.key] += 1
            msg = ev.msg.model_copy(update={"header": header})
            self.svc.process(ev.key, codec.encode(msg), codec.encoding_of(type(msg)), rx_time_ns=0)
        return [o.msg for o in self.svc.outbox[start:] if o.key == reply_key("group1")]


def test_the_service_in_the_loop_gives_the_in_process_events() -> None:
    sc, events = demo()
    sim = plugin(sc)
    assert isinstance(sim, InteractiveSimulator) and is_interactive(sim)
    spec = sim.exchange_spec()
    assert spec is not None and spec.reply_key == "fixstream/group/group1/reply" and spec.timeout_s == 10.0
    ex = ServiceExchange()
    online = list(sim.interact(ex))
    offline = list(plugin(sc).events())  # a fresh plugin of the same run: the in-process twin answers
    assert online == offline
    assert list(stamp(iter(offline), "player/default")) == list(events)  # = what fixstream play publishes
    assert ex.calls > 10 and ex.svc.counters.rejected == 0
    assert sim.sim is not None and sim.sim.protocol_violations == []
    # a reply names its request
    reply = next(o.msg for o in ex.svc.outbox if isinstance(o.msg, CoordinatorReply))
    assert spec.answers(reply) == ("player/default", uplink_key("group1", "base", "nodes"), 0)
    assert spec.answers(next(e.msg for e in events)) is None


def test_role_swap_of_the_demo() -> None:
    _, events = demo()
    assign = [e for e in events if e.key == nav_key("auv1", "assignment")]
    epochs = [(e.stamp_ns, e.msg.epoch, e.msg.leader_id, tuple(e.msg.follower_ids)) for e in assign]  # type: ignore[attr-defined]
    assert [x[1] for x in epochs] == [1, 2, 3]
    assert "auv3" in (epochs[1][2], *epochs[1][3]) and "auv3" not in (epochs[2][2], *epochs[2][3])
    statuses = [e.msg for e in events if e.key.startswith("fixstream/group/group1/uplink/auv3/")]
    assert [s.event for s in statuses] == ["DOCKED", "SERVICE_DONE", "DEPARTED"]  # type: ignore[attr-defined]
    done, departed = statuses[1].header.stamp_ns, statuses[2].header.stamp_ns
    assert done <= epochs[2][0] < departed  # re-assigned away from auv3 before it left
    # the beacons obey: after the swap no packet of auv3, and the packets carry the epoch in force
    packets = [e.msg.packet for e in events if e.key == sensor_key("auv4", "acoustic")]  # type: ignore[attr-defined]
    assert {p.assignment_epoch for p in packets} == {2, 3}
    late = [
        p
        for e, p in zip([e for e in events if e.key == sensor_key("auv4", "acoustic")], packets, strict=True)
        if e.stamp_ns > epochs[2][0] + 10e9
    ]
    assert late and all(p.sender_id != "auv3" and p.assignment_epoch == 3 for p in late)


def test_without_answers_the_group_keeps_its_assignment() -> None:
    sc, events = demo()
    calls = 0
    ex = ServiceExchange()

    def flaky(requests: list[Event]) -> list[Message]:
        nonlocal calls
        calls += 1
        replies = ex(requests)  # the coordinator decides (so its state goes on) ...
        return replies if requests[0].stamp_ns < 5e9 else []  # ... but nothing reaches the group after 5 s

    sim = plugin(sc)
    got = list(sim.interact(flaky))
    assigned = [e.msg for e in got if e.key == nav_key("auv1", "assignment")]
    assert [a.epoch for a in assigned if isinstance(a, BeaconAssignment)] == [1, 2]  # epoch 3 never arrived
    statuses = [e.msg.event for e in got if e.key.startswith("fixstream/group/group1/uplink/auv3/")]  # type: ignore[attr-defined]
    assert statuses == ["DOCKED", "SERVICE_DONE"]  # no grant: auv3 stays docked
    packets = [e.msg.packet for e in got if e.key == sensor_key("auv4", "acoustic")]  # type: ignore[attr-defined]
    assert packets and {p.assignment_epoch for p in packets} == {2}  # the group keeps navigating on epoch 2
    assert calls > 10 and got != list(events)


def test_open_loop_keeps_a_fixed_assignment() -> None:
    sc = scenario({"preset": "ref", "coordinator": False}, 60.0)
    sim = plugin(sc)
    assert sim.exchange_spec() is None and not is_interactive(sim)
    events = scenario_events(sc)
    assert not any(e.key.startswith("fixstream/group/") for e in events)
    assign = [e.msg for e in events if e.key == nav_key("auv4", "assignment")]
    assert len(assign) == 1 and isinstance(assign[0], BeaconAssignment) and assign[0].header.stamp_ns == 0
    assert (assign[0].leader_id, assign[0].follower_ids, assign[0].tau_s) == ("auv1", ["auv2", "auv3"], [0.5, 3.5])
    leaders = [e for e in events if e.key == sensor_key("auv4", "acoustic") and e.msg.packet.kind == "LEADER"]  # type: ignore[attr-defined]
    assert len(leaders) == 6  # the cycle at t = 0 too: the set is known from the start
    assert isinstance(next(e.msg for e in events if e.key == nav_key("auv4", "nodes")), BeaconTable)
    assert isinstance(next(e.msg for e in events if e.key == sensor_key("auv4", "dvl")), SpeedLog)
    assert isinstance(next(e.msg for e in events if e.key == nav_key("auv4", "status")), VehicleStatus)
    assert isinstance(leaders[0].msg, AcousticArrival)


def test_a_different_coordinator_configuration_is_warned_about(caplog: pytest.LogCaptureFixture) -> None:
    sc, _ = demo()
    sim = plugin(sc)
    other = CoordinatorService(CoordinatorSettings(instance="group1", grant_delay_s=20.0))
    other.run_offline([])

    def ask(requests: list[Event]) -> list[Message]:
        start = len(other.outbox)
        for ev in requests:
            other.process(ev.key, codec.encode(ev.msg), codec.encoding_of(type(ev.msg)), rx_time_ns=0)
        return [o.msg for o in other.outbox[start:] if isinstance(o.msg, CoordinatorReply)]

    list(sim.interact(ask))
    assert sim.digest_mismatch and "will differ from fixstream mc" in caplog.text


# ------------------------------------------------------------------------------------------------ files ---------
def test_the_scenario_files() -> None:
    names = {p.stem for p in SCENARIOS}
    expected = {f"rd_{n}_{p}" for n in ("ref", "low") for p in ("inside", "boundary", "outside")}
    expected |= {"rd_demo", "rd_fleet", "rd_ref_inside_variants", "rd_rob_racetrack"}
    expected |= {f"rd_rob_{x}" for x in ("multipath", "multipath_outside", "loss", "blackout", "clock_step")}
    expected |= {f"rd_rob_{x}" for x in ("clock_skew", "node_errors", "follower_jitter", "c_bias")}
    assert expected <= names
    for path in SCENARIOS:
        sc = load_scenario(path)
        assert sc.name == path.stem
        kinds = {s.kind for s in sc.simulators}
        assert kinds == {"rd_group"}, path
        instances = {f"{e.kind}/{e.instance}" for e in sc.estimators if e.kind == "rd_nav" and "-" not in e.instance}
        assert instances and instances <= set(sc.wait_for), path
        closed_loop = all(s.params.get("coordinator", True) for s in sc.simulators)  # open loop: nothing to wait for
        assert ("coordinator/group1" in sc.wait_for) == closed_loop and "recorder" in sc.wait_for, path
        for e in sc.estimators:
            if e.kind == "rd_nav":
                assert e.params["vehicle"] in e.instance, path
        cfg = plugin(sc).cfg
        assert cfg.duration_s == sc.duration_s
    faults = {
        "rd_rob_multipath": ("multipath_prob", 0.05),
        "rd_rob_loss": ("packet_loss", 0.2),
        "rd_rob_blackout": ("blackouts", [(3600.0, 4200.0)]),
        "rd_rob_clock_step": ("clock_steps", [(7202.0, 0.5)]),
        "rd_rob_clock_skew": ("clock_skew_ppm", 20.0),
        "rd_rob_node_errors": ("node_error_sigma_m", 0.5),
        "rd_rob_follower_jitter": ("sigma_f_s", 0.0002),
        "rd_rob_c_bias": ("c_bias_mps", 1.5),
    }
    for name, (field, value) in faults.items():
        assert getattr(plugin(load_scenario(REPO / "scenarios" / f"{name}.yaml")).cfg, field) == value, name
    assert plugin(load_scenario(REPO / "scenarios" / "rd_low_outside.yaml")).cfg.sigma_t_s == 0.1e-3
    assert plugin(load_scenario(REPO / "scenarios" / "rd_rob_racetrack.yaml")).cfg.vehicles[3].path == "racetrack"


def test_the_demo_is_short_with_four_auvs_and_a_role_swap() -> None:
    sc, events = demo()
    assert sc.duration_s <= 120.0
    vehicles = {e.msg.auv_id for e in events if isinstance(e.msg, VehicleStatus)}
    assert len(vehicles) >= 4
    epochs = {e.msg.epoch for e in events if isinstance(e.msg, BeaconAssignment)}
    assert len(epochs) >= 3  # two selections at the start, then the swap


def test_truth_matches_the_fix_frame_of_a_ned_run() -> None:
    """The simulation's own NED truth (the core tests' frame) and the plugin's ENU truth agree."""
    from services.rd_nav.simulation import Simulation, ref

    a = Simulation(ref("inside", duration_s=30.0, truth_period_s=1.0, truth_at_leader_arrivals=True), 1)
    b = Simulation(
        ref("inside", duration_s=30.0, truth_period_s=1.0, truth_at_leader_arrivals=True, truth_axes="enu"), 1
    )
    for x, y in zip(a.advance(30.0), b.advance(30.0), strict=True):
        if x.kind == "truth":
            assert isinstance(x.msg, Truth) and isinstance(y.msg, Truth)
            n, e, d = x.msg.position_m
            assert y.msg.position_m == pytest.approx([e, n, -d])
            assert np.hypot(*x.msg.velocity_mps[:2]) == pytest.approx(np.hypot(*y.msg.velocity_mps[:2]))
        else:
            assert x.msg == y.msg
