"""The pure simulation: determinism, ordering and headers, truth kinematics, plugins and their contract."""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from pydantic import Field
from test_scenario_files import REPO, nav_scenario

from schemas import BeaconRange, Header, SpeedLog, Truth
from services.player.scenario import Scenario, load_scenario, parse_scenario
from services.player.simulators import Event, ScenarioContext, SimParams, register
from services.player.timeline import SimulationError, run_seed, scenario_events
from shared import codec, keys


def _wire(events: list[Event]) -> list[tuple[int, str, bytes]]:
    return [(e.stamp_ns, e.key, codec.encode(e.msg)) for e in events]


def _scenario(doc: dict[str, Any]) -> Scenario:
    return parse_scenario(doc, "test")


def test_same_seed_gives_identical_events() -> None:
    s = _scenario(nav_scenario())
    assert _wire(scenario_events(s, 3)) == _wire(scenario_events(s, 3))
    assert _wire(scenario_events(s)) == _wire(scenario_events(s, s.seed))


def test_different_seed_changes_every_noise_stream_but_not_truth() -> None:
    s = _scenario(nav_scenario())
    a, b = scenario_events(s, 1), scenario_events(s, 2)
    assert [(e.stamp_ns, e.key) for e in a] == [(e.stamp_ns, e.key) for e in b]
    by_key: dict[str, list[bool]] = defaultdict(list)
    for x, y in zip(a, b, strict=True):
        by_key[x.key].append(codec.encode(x.msg) == codec.encode(y.msg))
    assert all(by_key[keys.truth("auv1")])
    for key, same in by_key.items():
        if key.startswith("fixstream/sensor/"):
            assert sum(same) == 0, key  # every sample of every sensor differs


def test_monte_carlo_run_seed_is_the_spawned_child() -> None:
    children = np.random.SeedSequence(42).spawn(5)
    for i, child in enumerate(children):
        assert np.array_equal(run_seed(42, i).generate_state(4), child.generate_state(4))
    s = _scenario(nav_scenario())
    assert _wire(scenario_events(s, 42, run=1)) != _wire(scenario_events(s, 42, run=2))


def test_noise_streams_are_keyed_by_sensor_not_by_position() -> None:
    doc = nav_scenario()
    extra = nav_scenario()
    extra["simulators"][0]["params"]["sensors"].insert(0, {"type": "speed_log", "id": "log9", "rate_hz": 3.0})
    a = [e for e in scenario_events(_scenario(doc), 5) if "log9" not in e.key]
    b = [e for e in scenario_events(_scenario(extra), 5) if "log9" not in e.key]
    assert _wire(a) == _wire(b)


def test_order_headers_and_counts() -> None:
    doc = nav_scenario(duration_s=10.0)
    events = scenario_events(_scenario(doc), 1, instance="p7")
    stamps = [e.stamp_ns for e in events]
    assert stamps == sorted(stamps) and stamps[0] == 0 and stamps[-1] == 10_000_000_000
    seqs: dict[str, list[int]] = defaultdict(list)
    for e in events:
        assert e.msg.header.stamp_ns == e.stamp_ns
        assert e.msg.header.source == "player/p7"
        assert e.msg.header.frame_id == "local_enu"
        seqs[e.key].append(e.msg.header.seq)
    for key, seq in seqs.items():
        assert seq == list(range(len(seq))), key
    counts = Counter(e.key for e in events)
    expected = {keys.truth("auv1"): 101}  # 10 Hz over [0, 10] s inclusive
    for sensor in doc["simulators"][0]["params"]["sensors"]:
        expected[keys.sensor("auv1", sensor["type"], sensor["id"])] = int(10 * sensor["rate_hz"]) + 1
    assert dict(counts) == expected


def _truth(events: list[Event]) -> list[Truth]:
    return [e.msg for e in events if isinstance(e.msg, Truth)]


def test_truth_position_integrates_velocity_and_matches_the_legs() -> None:
    doc = nav_scenario(truth_rate_hz=100.0, sensors=[])
    truths = _truth(scenario_events(_scenario(doc), 1))
    t = np.array([m.header.stamp_ns for m in truths]) * 1e-9
    pos = np.array([m.position_m for m in truths])
    vel = np.array([m.velocity_mps for m in truths])
    acc = np.array([m.acceleration_mps2 for m in truths])
    att = np.array([m.attitude_rad for m in truths])
    # independent check: trapezoidal integration of the velocity reproduces the position track. The climb
    # rate jumps by 0.4 m/s at 15 s and 30 s, exactly on a sample; each jump costs at most 0.4 * dt / 2.
    steps = 0.5 * (vel[1:] + vel[:-1]) * np.diff(t)[:, None]
    integrated = pos[0] + np.concatenate([np.zeros((1, 3)), np.cumsum(steps, 0)])
    assert np.max(np.abs(integrated - pos)) <= 2 * 0.4 * 0.01 / 2 + 1e-6
    # acceleration = derivative of velocity (central differences away from the leg boundaries)
    inside = [i for i in range(1, len(t) - 1) if all(abs(t[i] - b) > 0.02 for b in (15.0, 30.0, 45.0))]
    dv = (vel[2:] - vel[:-2]) / (t[2:] - t[:-2])[:, None]
    assert np.max(np.abs(dv[np.array(inside) - 1] - acc[inside])) < 1e-4
    # heading is the direction of the horizontal velocity, speed 2 m/s throughout
    assert np.allclose(np.mod(np.arctan2(vel[:, 0], vel[:, 1]), 2 * math.pi), att[:, 0], atol=1e-12)
    assert np.allclose(np.hypot(vel[:, 0], vel[:, 1]), 2.0)
    at = {round(x, 2): i for i, x in enumerate(t)}
    # leg 1: straight at 45 deg for 15 s from the origin at 30 m depth
    assert np.allclose(pos[at[15.0]], [30 / math.sqrt(2), 30 / math.sqrt(2), -30.0], atol=1e-9)
    # leg 2: 6 deg/s for 15 s -> heading 135 deg, diving 0.4 m/s -> 36 m; pitch atan(-0.4 / 2); roll atan(v w / g)
    assert math.isclose(att[at[30.0], 0], math.radians(135.0), abs_tol=1e-12)
    assert math.isclose(pos[at[30.0], 2], -36.0, abs_tol=1e-9)
    mid = at[22.5]
    assert math.isclose(att[mid, 1], math.atan2(-0.4, 2.0), abs_tol=1e-12)
    assert math.isclose(att[mid, 2], math.atan(2.0 * math.radians(6.0) / 9.80665), abs_tol=1e-12)
    # a 90 deg arc of radius v / w displaces the vehicle by R * sqrt(2) along the chord bearing 90 deg
    radius = 2.0 / math.radians(6.0)
    chord = pos[at[30.0], :2] - pos[at[15.0], :2]
    assert np.allclose(chord, [radius * math.sqrt(2), 0.0], atol=1e-9)
    # after the last leg the vehicle keeps flying straight and level
    assert np.allclose(vel[-1], [2 * math.sin(math.radians(135)), 2 * math.cos(math.radians(135)), 0.0])


def test_waypoint_route_passes_through_every_waypoint() -> None:
    wps = [[400.0, 0.0, -30.0], [400.0, 400.0, -50.0], [0.0, 0.0, -40.0]]
    doc = nav_scenario(
        duration_s=200.0,
        truth_rate_hz=20.0,
        sensors=[],
        legs=[],
        start={"position_m": [0.0, 0.0, -30.0], "heading_deg": 45.0, "speed_mps": 10.0},
        waypoints=[{"position_m": w} for w in wps],
        turn_rate_dps=6.0,
    )
    truths = _truth(scenario_events(_scenario(doc), 1))
    pos = np.array([m.position_m for m in truths])
    step = 10.0 / 20.0  # metres between truth samples
    for w in wps:
        d = np.linalg.norm(pos - np.array(w), axis=1)
        assert d.min() <= step / 2 + 1e-6, (w, d.min())
    # the vehicle never turns faster than the route's turn rate
    omega = np.array([m.extra["turn_rate_rps"] for m in truths])
    assert np.max(np.abs(omega)) <= math.radians(6.0) + 1e-12


class PingerParams(SimParams):
    platform: str
    beacon_m: list[float] = Field(min_length=3, max_length=3)
    rate_hz: float = 1.0


@register("test_pinger")
class Pinger:
    """A test plugin: slant range from a fixed beacon to a platform flown by an earlier simulator."""

    Params = PingerParams

    def __init__(self, params: PingerParams, rng: np.random.Generator, context: ScenarioContext) -> None:
        self.p, self.ctx = params, context
        self.source = context.platforms[params.platform]

    def events(self) -> Iterator[Event]:
        period = round(1e9 / self.p.rate_hz)
        stamps = np.arange(0, self.ctx.duration_ns + 1, period)
        truth = self.source.truth_at(stamps)
        for i, stamp in enumerate(stamps.tolist()):
            rng_m = float(np.linalg.norm(truth.position_m[i] - np.array(self.p.beacon_m)))
            msg = BeaconRange(header=self.ctx.header(stamp), beacon_id="b1", range_m=rng_m)
            yield Event(stamp, f"fixstream/sensor/{self.p.platform}/lbl/b1", msg)


@register("test_backwards")
class Backwards:
    Params = SimParams

    def __init__(self, params: SimParams, rng: np.random.Generator, context: ScenarioContext) -> None:
        self.ctx = context

    def events(self) -> Iterator[Event]:
        for stamp in (2_000_000_000, 1_000_000_000):
            yield Event(
                stamp,
                "fixstream/sensor/x/speed_log/s",
                SpeedLog(header=Header(stamp_ns=stamp), v_forward_mps=1.0, v_starboard_mps=0.0),
            )


def test_a_plugin_uses_an_earlier_platform_and_ties_keep_file_order() -> None:
    doc = nav_scenario(duration_s=5.0, sensors=[])
    doc["simulators"].append(
        {"kind": "test_pinger", "id": "ping", "params": {"platform": "auv1", "beacon_m": [100.0, -50.0, -80.0]}}
    )
    events = scenario_events(_scenario(doc), 1)
    truth_at = {e.stamp_ns: e.msg for e in events if isinstance(e.msg, Truth)}
    ranges = [e for e in events if isinstance(e.msg, BeaconRange)]
    assert len(ranges) == 6
    for r in ranges:
        assert isinstance(r.msg, BeaconRange) and r.msg.range_m is not None
        expected = math.dist(truth_at[r.stamp_ns].position_m, [100.0, -50.0, -80.0])
        assert math.isclose(r.msg.range_m, expected, rel_tol=1e-12)
    order = [e.key for e in events if e.stamp_ns == 1_000_000_000]
    assert order == [keys.truth("auv1"), "fixstream/sensor/auv1/lbl/b1"]
    # the same tie the other way round when the pinger is listed first (it needs the platform, so it fails)
    doc["simulators"].reverse()
    with pytest.raises(SimulationError, match="'ping'"):
        scenario_events(_scenario(doc), 1)


def test_a_simulator_that_breaks_stamp_order_is_caught() -> None:
    doc = nav_scenario(duration_s=5.0)
    doc["simulators"].append({"kind": "test_backwards", "id": "bad", "params": {}})
    with pytest.raises(SimulationError, match="simulator 'bad': stamp 1000000000 ns after 2000000000 ns"):
        scenario_events(_scenario(doc), 1)


def test_demo_file_is_deterministic_across_loads() -> None:
    a = scenario_events(load_scenario(REPO / "scenarios" / "demo.yaml"))
    b = scenario_events(load_scenario(REPO / "scenarios" / "demo.yaml"))
    assert _wire(a) == _wire(b) and len(a) > 2000
