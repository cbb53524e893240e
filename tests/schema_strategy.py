"""Hypothesis strategies for objects valid against the project's exported JSON Schemas (``schemas/json``).

The exported schemas use a small part of JSON Schema (object/properties/required, number and integer bounds,
string lengths, arrays with item counts, enum, anyOf, $ref to $defs), so the strategy is written here rather
than taken from hypothesis-jsonschema, whose last release no longer runs with the locked Hypothesis. Numbers and
integers are drawn at their bounds more often than anywhere else: valid but extreme values are the point. One
rule goes beyond the schema: a field holding a Gaussian estimate block gets a block of the layout the field
declares (``x-components``), see :func:`_gaussian_block`.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

from hypothesis import strategies as st

SCHEMAS = Path(__file__).resolve().parents[1] / "schemas" / "json"
#: unbounded numbers get these magnitudes (the extremes a float field without a physical bound must survive)
_HUGE = [0.0, -0.0, 1e-300, -1e-300, 1e300, -1e300, 1.7976931348623157e308, -1.7976931348623157e308]


@cache
def schema(model: str) -> dict[str, Any]:
    return json.loads((SCHEMAS / f"{model}.json").read_text())  # type: ignore[no-any-return]


def message_dicts(model: str) -> st.SearchStrategy[dict[str, Any]]:
    """Objects valid against the JSON Schema of ``model`` (checks the schema cannot express may still fail)."""
    root = schema(model)
    return _strategy(root, root.get("$defs", {}))  # type: ignore[return-value]


def _number(s: dict[str, Any], integer: bool) -> st.SearchStrategy[Any]:
    lo = s.get("minimum", s.get("exclusiveMinimum"))
    hi = s.get("maximum", s.get("exclusiveMaximum"))
    excl_lo, excl_hi = "exclusiveMinimum" in s, "exclusiveMaximum" in s
    if integer:
        lo_i = None if lo is None else int(lo) + (1 if excl_lo else 0)
        hi_i = None if hi is None else int(hi) - (1 if excl_hi else 0)
        edges = [v for v in (lo_i, hi_i, 0, 1) if v is not None and (lo_i is None or v >= lo_i)]
        edges = [v for v in edges if hi_i is None or v <= hi_i]
        lo_i = -(2**63) if lo_i is None else lo_i
        hi_i = 2**63 - 1 if hi_i is None else hi_i
        return st.one_of(st.sampled_from(edges or [lo_i]), st.integers(lo_i, hi_i))
    floats = st.floats(
        min_value=lo,
        max_value=hi,
        exclude_min=excl_lo,
        exclude_max=excl_hi,
        allow_nan=False,
        allow_infinity=False,
    )
    edges_f = [v for v in (lo, hi) if v is not None and not ((v == lo and excl_lo) or (v == hi and excl_hi))]
    edges_f += [v for v in _HUGE if (lo is None or v > lo or (v == lo and not excl_lo)) and (hi is None or v < hi)]
    return st.one_of(st.sampled_from(edges_f), floats) if edges_f else floats


def _gaussian_block(s: dict[str, Any], defs: dict[str, Any]) -> st.SearchStrategy[dict[str, Any]]:
    """A GaussianEstimate block of the layout its field declares (``x-components``, ``x-units``), so the block is
    valid and the message around it can be: the mean drawn as any number field, the covariance a diagonal of
    variances drawn to their extremes (positive semi-definite as the schema's Cholesky check wants). Without
    this rule the four lists would almost never have the one common length the block's validator asks for."""
    comps, units = s["x-components"], s["x-units"]
    n = len(comps)
    variance = st.one_of(st.sampled_from([0.0, 1e-300, 1.0, 1e300]), st.floats(0.0, 1e12))
    number = _number({}, integer=False)
    frame = _strategy(defs["GaussianEstimate"]["properties"]["frame"], defs)

    def matrix(diag: list[float]) -> list[list[float]]:
        return [[diag[i] if i == j else 0.0 for j in range(n)] for i in range(n)]

    return st.fixed_dictionaries(
        {
            "frame": frame,
            "components": st.just(list(comps)),
            "units": st.just(list(units)),
            "mean": st.lists(number, min_size=n, max_size=n),
            "covariance": st.lists(variance, min_size=n, max_size=n).map(matrix),
        }
    )


def _strategy(s: dict[str, Any], defs: dict[str, Any]) -> st.SearchStrategy[Any]:
    if "x-components" in s:  # a GaussianEstimate field (or an optional one: anyOf with null)
        block = _gaussian_block(s, defs)
        return st.one_of(st.none(), block) if "anyOf" in s else block
    if "$ref" in s:
        return st.deferred(lambda: _strategy(defs[s["$ref"].split("/")[-1]], defs))
    if "anyOf" in s:
        return st.one_of([_strategy(sub, defs) for sub in s["anyOf"]])
    if "enum" in s:
        return st.sampled_from(s["enum"])
    if "const" in s:
        return st.just(s["const"])
    kind = s.get("type")
    if kind == "null":
        return st.none()
    if kind == "boolean":
        return st.booleans()
    if kind in ("number", "integer"):
        return _number(s, kind == "integer")
    if kind == "string":
        lo, hi = s.get("minLength", 0), min(s.get("maxLength", 64), 64)
        long = s.get("maxLength")
        text = st.text(min_size=lo, max_size=max(lo, hi))
        return st.one_of(text, st.just("x" * long)) if long and long <= 100_000 and long >= lo else text
    if kind == "array":
        items = s.get("items", {})
        lo, hi = s.get("minItems", 0), min(s.get("maxItems", 8), 8)
        return st.lists(_strategy(items, defs), min_size=lo, max_size=max(lo, hi))
    if kind == "object":
        props: dict[str, Any] = s.get("properties", {})
        required = set(s.get("required", []))
        if not props:
            extra = s.get("additionalProperties", {})
            value = _strategy(extra, defs) if isinstance(extra, dict) else st.integers()
            return st.dictionaries(st.text(min_size=1, max_size=20), value, max_size=min(s.get("maxProperties", 6), 6))
        fields = {k: _strategy(v, defs) for k, v in props.items() if k in required}
        optional = {k: _strategy(v, defs) for k, v in props.items() if k not in required}
        return st.fixed_dictionaries(fields, optional=optional)
    return st.none()
