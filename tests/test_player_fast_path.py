"""The player's fast path publishes exactly what the per-message path publishes (issue 18, item 3).

The reference is :func:`services.player.timeline.scenario_events` encoded with :func:`shared.codec.encode`: a pydantic
model per message, stamped by ``model_copy`` — the path the player took before it encoded columns. The fast path is
:func:`services.player.wire.wire_events` (what ``play_scenario`` puts, in order). Compared: the key, the encoding
string and the payload bytes of every message, in order (so also the same order per key). A Zenoh-level check of
the same thing is ``tests/test_player_zenoh.py::test_every_event_arrives_in_order_with_seq_and_the_end_marker_counts``.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from test_scenario_files import BASE_PLATFORM, REPO

from schemas import Depth, SpeedLog, Truth
from schemas.base import VEC_COMPONENT_MAX
from services.player.column_encoding import RowEncoder, uint_class
from services.player.scenario import Scenario, load_scenario, parse_scenario
from services.player.simulators import Event, ScenarioContext, SimParams, register
from services.player.simulators.columns import CHUNK_ROWS, ColumnStream
from services.player.timeline import build, scenario_events
from services.player.wire import wire_events
from shared import codec

SOURCE = "player/fast"


def reference(scenario: Scenario, seed: int | None = None) -> list[tuple[str, str, bytes]]:
    return [
        (e.key, codec.encoding_of(type(e.msg)), codec.encode(e.msg))
        for e in scenario_events(scenario, seed, instance="fast")
    ]


def fast(scenario: Scenario, seed: int | None = None) -> list[tuple[str, str, bytes]]:
    sim = build(scenario, scenario.seed if seed is None else seed)
    return [(w.key, w.encoding, w.payload) for w in wire_events(sim, SOURCE)]


@pytest.mark.parametrize(
    "name",
    # demo: nav_platform (every sensor type) merged with five other simulators, one of them interactive;
    # the others have no nav_platform and go through the per-event path
    ["demo", "lbl_nav_demo", "attitude_demo", "terrain_nav_demo", "pcl_tracker_demo", "rd_demo"],
)
def test_shipped_scenarios_publish_the_same_bytes(name: str) -> None:
    scenario = load_scenario(REPO / "scenarios" / f"{name}.yaml")
    expected = reference(scenario)
    assert fast(scenario) == expected
    assert len(expected) > 50


def _platform(name: str, **over: Any) -> dict[str, Any]:
    params = copy.deepcopy(BASE_PLATFORM)
    params["platform"] = name
    params.update(over)
    return params


def test_two_platforms_every_sensor_kind_stamps_beyond_two_to_the_32_ns() -> None:
    """Ties between platforms and sensors (same rates), an INS without velocities, a late-starting sensor, a speed
    log and a DVL, 8 s of data so that stamps cross 2**32 ns (the stamp's msgpack width changes) and seqs cross 255."""
    sensors = [
        *BASE_PLATFORM["sensors"],
        {"type": "speed_log", "id": "log0", "rate_hz": 40.0, "sigma_mps": 0.1},
        {"type": "ins", "id": "ins1", "rate_hz": 10.0, "report_velocity": False, "start_s": 1.25},
        {"type": "heading", "id": "gyro1", "rate_hz": 50.0, "white_sigma_deg": 0.2},
    ]
    doc = {
        "name": "fast",
        "seed": 3,
        "duration_s": 8.0,
        "simulators": [
            {"kind": "nav_platform", "id": "a", "params": _platform("auv1", sensors=sensors)},
            {"kind": "nav_platform", "id": "b", "params": _platform("auv2", sensors=sensors, truth_rate_hz=40.0)},
        ],
    }
    scenario = parse_scenario(doc)
    expected = reference(scenario, 5)
    assert fast(scenario, 5) == expected
    assert len(expected) > 2000


class _KeyedParams(SimParams):
    key: str
    stamps_s: list[float]


@register("fast_path_test_keyed")
class _KeyedEvents:
    """Depth messages on a key of the scenario's choice, one per stamp (to share a key with ``nav_platform``)."""

    Params = _KeyedParams

    def __init__(self, params: _KeyedParams, rng: np.random.Generator, context: ScenarioContext) -> None:
        self.params, self.context = params, context

    def events(self) -> Iterator[Event]:
        for t in self.params.stamps_s:
            ns = round(t * 1e9)
            yield Event(ns, self.params.key, Depth(header=self.context.header(ns), depth_m=1.0 + t))


def test_another_simulator_on_a_column_key_shares_its_seq_and_keeps_tie_order() -> None:
    """Events of an event-based simulator on nav_platform's depth key, some at the depth sensor's own stamps (ties:
    simulator order decides), listed before and after the platform: seq counts both, in merged order."""
    key = "fixstream/sensor/auv1/depth/press0"
    stamps = [0.0, 0.5, 0.75, 2.0, 2.0, 3.1, 9.5]
    for first in (True, False):
        keyed = {"kind": "fast_path_test_keyed", "id": "k", "params": {"key": key, "stamps_s": stamps}}
        platform = {"kind": "nav_platform", "id": "a", "params": _platform("auv1")}
        doc = {
            "name": "shared",
            "seed": 1,
            "duration_s": 10.0,
            "simulators": [keyed, platform] if first else [platform, keyed],
        }
        scenario = parse_scenario(doc)
        expected = reference(scenario)
        assert fast(scenario) == expected
        assert sum(k == key for k, _, _ in expected) == 21 + len(stamps)


# ---- the encoder alone: any values, stamps and seqs -----------------------------------------------------------------

_speed = st.floats(-30.0, 30.0, allow_nan=False, allow_infinity=False)
_any = st.floats(allow_nan=False, allow_infinity=False)
#: a vector component, anywhere in the schema's range (Vec3: within ±VEC_COMPONENT_MAX), its ends included
_component = st.one_of(
    st.floats(-VEC_COMPONENT_MAX, VEC_COMPONENT_MAX), st.sampled_from([VEC_COMPONENT_MAX, -VEC_COMPONENT_MAX, 5e-324])
)
_uint62 = st.integers(0, 2**62)
# values at the msgpack width boundaries, so that every class and every class change is drawn often
_edges = st.sampled_from([0, 1, 127, 128, 255, 256, 65535, 65536, 2**32 - 1, 2**32, 2**62])


@settings(max_examples=60, deadline=None)
@given(
    rows=st.lists(st.tuples(_speed, _speed, _speed), min_size=1, max_size=40),
    stamps=st.lists(st.one_of(_uint62, _edges), min_size=40, max_size=40),
    seqs=st.lists(st.one_of(st.integers(0, 2**63 - 1), _edges), min_size=40, max_size=40),
)
def test_speed_log_rows_encode_as_their_messages(
    rows: list[tuple[float, float, float]], stamps: list[int], seqs: list[int]
) -> None:
    n = len(rows)
    values = np.array(rows)
    stream = ColumnStream(
        "fixstream/sensor/p/dvl/d",
        SpeedLog,
        "local_enu",
        np.array(sorted(stamps[:n]), dtype=np.int64),
        {"v_forward_mps": values[:, 0], "v_starboard_mps": values[:, 1], "v_down_mps": values[:, 2]},
        {"avg_interval_s": 0.2, "bottom_lock": False},
    )
    got = RowEncoder(stream, SOURCE, np.array(seqs[:n], dtype=np.int64)).take(n)
    assert got == [codec.encode_stamped(stream.message(i), SOURCE, seqs[i]) for i in range(n)]


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(1, 12),
    data=st.data(),
)
def test_truth_rows_with_lists_and_a_nested_dict_encode_as_their_messages(n: int, data: st.DataObject) -> None:
    matrix = st.lists(st.lists(_component, min_size=3, max_size=3), min_size=n, max_size=n)
    stamps = sorted(data.draw(st.lists(st.one_of(_uint62, _edges), min_size=n, max_size=n)))
    seqs = data.draw(st.lists(st.one_of(st.integers(0, 2**63 - 1), _edges), min_size=n, max_size=n))
    columns = {
        "position_m": np.array(data.draw(matrix)),
        "attitude_rad": np.array(data.draw(matrix)),
        "extra.a": np.array(data.draw(st.lists(_any, min_size=n, max_size=n))),
        "extra.b": np.array(data.draw(st.lists(_any, min_size=n, max_size=n))),
    }
    stream = ColumnStream("fixstream/truth/p", Truth, "f", np.array(stamps, dtype=np.int64), columns, {"platform": "p"})
    got = RowEncoder(stream, SOURCE, np.array(seqs, dtype=np.int64)).take(n)
    assert got == [codec.encode_stamped(stream.message(i), SOURCE, seqs[i]) for i in range(n)]


def test_blocks_chunk_boundaries_width_changes_and_shifts() -> None:
    """Rows taken in uneven pieces across the encoder's blocks, stamps crossing 2**32 ns inside a block, seqs
    crossing 255 and 65535, and a shift of the seq half way (another publisher's message on the key)."""
    n = CHUNK_ROWS + 1500
    rng = np.random.default_rng(4)
    stamps = np.linspace(0, 2 * 2**32, n).astype(np.int64)
    seqs = np.arange(n, dtype=np.int64) + 65_000
    depth = rng.uniform(-20.0, 11_000.0, n)
    stream = ColumnStream("fixstream/sensor/p/depth/d", Depth, "local_enu", stamps, {"depth_m": depth})
    assert len(set(uint_class(stamps).tolist())) > 1 and len(set(uint_class(seqs).tolist())) > 1
    encoder = RowEncoder(stream, SOURCE, seqs)
    got: list[bytes] = []
    for m in (1, 999, 3000, 500):
        got += encoder.take(m)
    encoder.shift(2)
    got += encoder.take(n - len(got))
    with pytest.raises(IndexError):
        encoder.take(1)
    want_seqs = seqs.copy()
    want_seqs[4500:] += 2
    want = [codec.encode_stamped(stream.message(i), SOURCE, int(want_seqs[i])) for i in range(n)]
    assert got == want


def test_a_stream_with_a_column_that_is_not_float_is_encoded_through_its_dict() -> None:
    """A bool column (msgpack width is not that of a float): the slower per-row path, the same bytes."""
    n = 50
    stream = ColumnStream(
        "fixstream/sensor/p/dvl/d",
        SpeedLog,
        "local_enu",
        np.arange(n, dtype=np.int64) * 10**8,
        {"v_forward_mps": np.linspace(-1, 1, n), "v_starboard_mps": np.zeros(n), "bottom_lock": np.arange(n) % 2 == 0},
    )
    encoder = RowEncoder(stream, SOURCE, np.arange(n, dtype=np.int64))
    assert encoder.pieces is None
    assert encoder.take(n) == [codec.encode_stamped(stream.message(i), SOURCE, i) for i in range(n)]


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.one_of(st.floats(-40.0, 11_040.0), st.sampled_from([-20.0, 11_000.0, float("nan"), float("inf")])),
        min_size=1,
        max_size=30,
    )
)
def test_validate_refuses_a_stream_exactly_when_some_row_is_not_a_valid_message(values: list[float]) -> None:
    """Checking only the extreme and non-finite rows is enough for interval constraints (Depth: -20 <= d <= 11000,
    finite): the stream is refused if and only if building some row's message fails."""
    n = len(values)
    stream = ColumnStream("k", Depth, "f", np.arange(n, dtype=np.int64), {"depth_m": np.array(values)})
    any_invalid = False
    for i in range(n):
        try:
            stream.message(i)
        except ValidationError:
            any_invalid = True
    if any_invalid:
        with pytest.raises(ValidationError):
            stream.validate()
    else:
        stream.validate()


def test_a_column_only_run_matches() -> None:
    """The throughput benchmark's shape (four AUVs, five 1 kHz sensors each, ``bench/bench_throughput.py``) for 1.5 s:
    only column streams, so the whole run is one stable sort and no per-event merge."""
    sensors = [
        {"type": "dvl", "id": "dvl0", "rate_hz": 1000.0, "sigma_mps": 0.01},
        {"type": "speed_log", "id": "log0", "rate_hz": 1000.0, "sigma_mps": 0.1},
        {"type": "heading", "id": "gyro0", "rate_hz": 1000.0, "white_sigma_deg": 0.1},
        {"type": "depth", "id": "press0", "rate_hz": 1000.0, "sigma_m": 0.05},
        {"type": "heading", "id": "gyro1", "rate_hz": 1000.0, "white_sigma_deg": 0.2},
    ]
    platforms = [
        _platform(f"auv{p}", sensors=sensors, legs=[{"duration_s": 1.5, "turn_rate_dps": 0.5}]) for p in range(4)
    ]
    doc = {
        "name": "columns",
        "seed": 1,
        "duration_s": 1.5,
        "simulators": [{"kind": "nav_platform", "id": p["platform"], "params": p} for p in platforms],
    }
    scenario = parse_scenario(doc)
    expected = reference(scenario)
    assert fast(scenario) == expected
    assert len(expected) == 4 * (5 * 1501 + 16)
