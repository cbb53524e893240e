"""Contract tests: every model round-trips through msgpack and JSON; bad payloads are rejected."""

from __future__ import annotations

import json
import math
from typing import Any

import msgpack
import pytest
from samples import all_examples

from schemas import MODELS, BeaconRange, Fix, Message
from schemas.export import JSON_DIR, render
from shared import codec

NAMES = sorted(MODELS)


@pytest.mark.parametrize("name", NAMES)
def test_msgpack_round_trip_is_exact(name: str) -> None:
    msg = all_examples()[name]
    data = codec.encode(msg)
    back = codec.decode(data, codec.encoding_of(type(msg)))
    assert type(back) is type(msg)
    assert back == msg
    assert codec.encode(back) == data


@pytest.mark.parametrize("name", NAMES)
def test_json_round_trip_is_exact(name: str) -> None:
    msg = all_examples()[name]
    text = msg.model_dump_json()
    back = type(msg).model_validate_json(text)
    assert back == msg
    # JSON mode dump also validates strictly through the codec path
    assert codec.validate(type(msg), json.loads(text)) == msg


@pytest.mark.parametrize("name", NAMES)
def test_exported_json_schema_is_current(name: str) -> None:
    path = JSON_DIR / f"{name}.json"
    assert path.exists(), f"{path} missing: run `make schemas`"
    assert path.read_text() == render(name), f"{path} is stale: run `make schemas`"


def test_no_orphan_schema_files() -> None:
    assert {p.stem for p in JSON_DIR.glob("*.json")} == set(MODELS)


def _payload(msg: Message) -> dict[str, object]:
    return msg.model_dump(mode="python")


def _first_float_path(obj: object, path: tuple[object, ...] = ()) -> tuple[object, ...] | None:
    if isinstance(obj, float):
        return path
    if isinstance(obj, dict):
        for k, v in obj.items():
            if k == "header":
                continue
            found = _first_float_path(v, (*path, k))
            if found is not None:
                return found
    if isinstance(obj, list):
        for i, v in enumerate(obj):
            found = _first_float_path(v, (*path, i))
            if found is not None:
                return found
    return None


def _set(obj: dict[str, object], path: tuple[object, ...], value: object) -> None:
    cur: object = obj
    for p in path[:-1]:
        cur = cur[p]  # type: ignore[index]
    cur[path[-1]] = value  # type: ignore[index]


FLOAT_MODELS = [n for n in NAMES if _first_float_path(_payload(all_examples()[n])) is not None]


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("name", FLOAT_MODELS)
def test_non_finite_floats_are_rejected(name: str, bad: float) -> None:
    msg = all_examples()[name]
    obj = _payload(msg)
    path = _first_float_path(obj)
    assert path is not None
    _set(obj, path, bad)
    with pytest.raises(codec.DecodeError) as info:
        codec.decode(msgpack.packb(obj), codec.encoding_of(type(msg)))
    assert info.value.reason == "non_finite"


@pytest.mark.parametrize("name", NAMES)
def test_wrong_type_missing_and_extra_fields_are_rejected(name: str) -> None:
    msg = all_examples()[name]
    enc = codec.encoding_of(type(msg))
    obj = _payload(msg)

    wrong = dict(obj, header=dict(obj["header"], stamp_ns="now"))  # type: ignore[arg-type]
    with pytest.raises(codec.DecodeError) as info:
        codec.decode(msgpack.packb(wrong), enc)
    assert info.value.reason == "wrong_type"

    missing = {k: v for k, v in obj.items() if k != "header"}
    with pytest.raises(codec.DecodeError) as info:
        codec.decode(msgpack.packb(missing), enc)
    assert info.value.reason == "missing_field"

    extra = dict(obj, garbage=[1, 2, 3])
    with pytest.raises(codec.DecodeError) as info:
        codec.decode(msgpack.packb(extra), enc)
    assert info.value.reason == "extra_field"


@pytest.mark.parametrize("name", NAMES)
def test_truncated_and_padded_msgpack_is_rejected(name: str) -> None:
    msg = all_examples()[name]
    enc = codec.encoding_of(type(msg))
    data = codec.encode(msg)
    for cut in (1, len(data) // 2, len(data) - 1):
        with pytest.raises(codec.DecodeError) as info:
            codec.decode(data[:cut], enc)
        assert info.value.reason in {"bad_msgpack", "wrong_type", "missing_field", "invalid"}
    with pytest.raises(codec.DecodeError) as info:
        codec.decode(data + b"\xc0", enc)
    assert info.value.reason == "trailing_bytes"


def test_unknown_schema_and_version_are_rejected() -> None:
    data = codec.encode(all_examples()["Depth"])
    for enc, reason in [
        ("application/msgpack;fixstream.NoSuchModel/1", "unknown_schema"),
        ("application/msgpack;fixstream.Depth/99", "schema_version"),
        ("application/json", "bad_encoding"),
    ]:
        with pytest.raises(codec.DecodeError) as info:
            codec.decode(data, enc)
        assert info.value.reason == reason


def test_physical_bounds_and_one_of_rules() -> None:
    h = {"stamp_ns": 1}
    with pytest.raises(codec.DecodeError) as info:
        codec.validate(BeaconRange, {"header": h, "beacon_id": "b", "range_m": -5.0})
    assert info.value.reason == "out_of_bounds"
    with pytest.raises(codec.DecodeError):
        codec.validate(BeaconRange, {"header": h, "beacon_id": "b"})
    with pytest.raises(codec.DecodeError):
        codec.validate(BeaconRange, {"header": h, "beacon_id": "b", "range_m": 5.0, "travel_time_s": 0.1})


def test_covariance_must_be_symmetric_positive_semidefinite() -> None:
    good: dict[str, Any] = _payload(all_examples()["Fix"])
    codec.validate(Fix, good)

    def with_cov(cov: list[list[float]]) -> dict[str, Any]:
        return dict(good, estimate=dict(good["estimate"], covariance=cov))

    for bad, why in [
        ([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "not symmetric"),
        ([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "positive semi-definite"),
        ([[1.0, 0.0], [0.0, 1.0]], "one entry"),
    ]:
        with pytest.raises(codec.DecodeError) as info:
            codec.validate(Fix, with_cov(bad))
        assert why in info.value.detail
