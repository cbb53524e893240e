"""Codec cost per model: msgpack encode and strict decode+validate, in µs per message."""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from samples import all_examples

from shared import codec

from .report import emit


def per_call_us(fn, budget_s: float = 0.2) -> float:  # type: ignore[no-untyped-def]
    n = 0
    t0 = time.perf_counter()
    while True:
        for _ in range(100):
            fn()
        n += 100
        dt = time.perf_counter() - t0
        if dt >= budget_s:
            return dt / n * 1e6


def main() -> None:
    rows = []
    figures: dict[str, dict[str, float]] = {}
    for name, msg in sorted(all_examples().items()):
        enc = codec.encoding_of(type(msg))
        data = codec.encode(msg)
        e_us = per_call_us(lambda msg=msg: codec.encode(msg))
        d_us = per_call_us(lambda data=data, enc=enc: codec.decode(data, enc))
        rows.append((name, len(data), e_us, d_us))
        figures[name] = {"bytes": len(data), "encode_us": round(e_us, 3), "decode_us": round(d_us, 3)}
    emit("codec", ["model", "bytes", "encode µs", "decode+validate µs"], rows, {"per_model": figures})


if __name__ == "__main__":
    main()
