"""Hostile payloads for a fuzz campaign over real processes (tests/test_faults.py; FIXSTREAM_FUZZ_N=20000: full size).

Deterministic for a seed: mutations of a service's real inputs (stamps at and beyond the bounds, going
backwards, seq at its extremes, NaN and infinity in float fields, truncation, flipped bytes, trailing bytes,
unknown fields, wrong or unknown encodings, another model's payload), random bytes, oversized and deeply nested
msgpack, and markers from foreign sources. Each item is (key, payload, encoding).
"""

from __future__ import annotations

from collections.abc import Sequence

import msgpack
import numpy as np

from schemas import Header, Message, ScenarioMarker
from schemas.base import MAX_STAMP_NS
from shared import codec, keys

Raw = tuple[str, bytes, str]

KINDS = (
    "random_bytes",
    "truncated",
    "flipped",
    "trailing",
    "stamp_max",
    "stamp_beyond",
    "stamp_u64",
    "stamp_negative",
    "stamp_backwards",
    "seq_extreme",
    "nan",
    "inf",
    "unknown_field",
    "wrong_type",
    "bad_encoding",
    "unknown_schema",
    "other_model",
    "duplicate",
    "oversized",
    "deep",
    "wide_map",
    "foreign_marker",
)


def _mutate_floats(obj: object, value: float, rng: np.random.Generator) -> object:
    if isinstance(obj, float):
        return value if rng.random() < 0.5 else obj
    if isinstance(obj, dict):
        return {k: _mutate_floats(v, value, rng) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_mutate_floats(v, value, rng) for v in obj]
    return obj


def _with_header(obj: dict[str, object], **changes: object) -> dict[str, object]:
    header = obj.get("header")
    return {**obj, "header": {**header, **changes}} if isinstance(header, dict) else obj


def _pack(obj: object) -> bytes:
    try:
        return msgpack.packb(obj, use_bin_type=True)  # type: ignore[no-any-return]
    except (OverflowError, ValueError, TypeError):
        return b"\xc1"


def hostile_items(inputs: Sequence[tuple[str, Message]], n: int, seed: int) -> list[Raw]:
    """``n`` hostile samples on the keys of ``inputs`` (a service's real inputs), from ``seed``."""
    rng = np.random.default_rng(seed)
    out: list[Raw] = []
    last: Raw | None = None
    for _ in range(n):
        key, msg = inputs[int(rng.integers(len(inputs)))]
        enc = codec.encoding_of(type(msg))
        good = codec.encode_stamped(msg, "fuzz/client", int(rng.integers(1 << 20)))
        obj: dict[str, object] = codec.unpack(good)
        kind = KINDS[int(rng.integers(len(KINDS)))]
        if kind == "random_bytes":
            item: Raw = (key, rng.bytes(int(rng.integers(0, 400))), enc)
        elif kind == "truncated":
            item = (key, good[: int(rng.integers(0, max(len(good), 1)))], enc)
        elif kind == "flipped":
            b = bytearray(good)
            for _ in range(int(rng.integers(1, 5))):
                b[int(rng.integers(len(b)))] ^= 1 << int(rng.integers(8))
            item = (key, bytes(b), enc)
        elif kind == "trailing":
            item = (key, good + b"\x00", enc)
        elif kind == "stamp_max":
            item = (key, _pack(_with_header(obj, stamp_ns=MAX_STAMP_NS)), enc)
        elif kind == "stamp_beyond":
            item = (key, _pack(_with_header(obj, stamp_ns=MAX_STAMP_NS + 1)), enc)
        elif kind == "stamp_u64":
            item = (key, _pack(_with_header(obj, stamp_ns=2**64 - 1)), enc)
        elif kind == "stamp_negative":
            item = (key, _pack(_with_header(obj, stamp_ns=-1)), enc)
        elif kind == "stamp_backwards":
            item = (key, _pack(_with_header(obj, stamp_ns=max(0, msg.header.stamp_ns - 10**9))), enc)
        elif kind == "seq_extreme":
            item = (key, _pack(_with_header(obj, seq=int(rng.choice([2**63 - 1, 2**64 - 1])))), enc)
        elif kind in ("nan", "inf"):
            value = float("nan") if kind == "nan" else float("inf") * float(rng.choice([-1, 1]))
            item = (key, _pack(_mutate_floats(obj, value, rng)), enc)
        elif kind == "unknown_field":
            item = (key, _pack({**obj, "evil": 1}), enc)
        elif kind == "wrong_type":
            field = next((k for k in obj if k != "header"), "header")
            item = (key, _pack({**obj, field: "not this"}), enc)
        elif kind == "bad_encoding":
            item = (key, good, "application/json")
        elif kind == "unknown_schema":
            item = (key, good, "application/msgpack;fixstream.NoSuchModel/1")
        elif kind == "other_model":
            item = (key, good, codec.encoding_of(ScenarioMarker))
        elif kind == "duplicate" and last is not None:
            item = last
        elif kind == "oversized":
            item = (key, b"\x00" * (2 << 20), enc)
        elif kind == "deep":
            item = (key, b"\x91" * 5000 + b"\xc0", enc)
        elif kind == "wide_map":
            item = (key, _pack({str(i): i for i in range(codec.MAX_MAP_LEN + 10)}), enc)
        elif kind == "foreign_marker":
            marker = ScenarioMarker(
                header=Header(stamp_ns=msg.header.stamp_ns, source="evil/client"),
                event="end" if rng.random() < 0.5 else "start",
                scenario="x",
                seed=0,
            )
            item = (keys.scenario("x"), codec.encode(marker), codec.encoding_of(ScenarioMarker))
        else:
            item = (key, good, enc)  # a valid message from a foreign source
        out.append(item)
        last = item
    return out
