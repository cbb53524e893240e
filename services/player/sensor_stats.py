"""The built-in ``sensor_stats`` metric: per sensor stream, the count and the error statistics against truth.

For every key ``fixstream/sensor/<platform>/<kind>/<id>`` the error ``measured - true`` of each component
is taken at the message's stamp, using the platform's exact truth when a simulator registered it (the
trajectory), else linear interpolation of the ``fixstream/truth/<platform>`` messages. Angles are wrapped
to [-pi, pi). Units are those of the message fields (m, m/s, rad).

Components per message type (true value in the scenario's east/north/up frame):

* ``SpeedLog``: ``v_forward_mps``, ``v_starboard_mps`` (level frame along/across the true heading),
  ``v_down_mps`` (= -up velocity)
* ``Heading``: ``heading_rad``
* ``Attitude``: ``heading_rad``, ``pitch_rad``, ``roll_rad``
* ``Depth``: ``depth_m`` (= -up)
* ``InsSample``: ``x_m`` (north), ``z_m`` (east), ``h_m`` (up), ``vx_mps``, ``vz_mps``, ``vh_mps``

Other message types are counted only; :func:`register_error_model` adds one.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from schemas import Attitude, Depth, Heading, InsSample, Message, SpeedLog, Truth
from shared import keys
from shared.filters.angles import wrap_pi_left

from .simulators import Event, TruthSource, TruthState

ErrorModel = Callable[[Sequence[Any], TruthState], dict[str, np.ndarray]]

ERROR_MODELS: dict[type[Message], ErrorModel] = {}


def register_error_model(model: type[Message], fn: ErrorModel) -> None:
    """Teach ``sensor_stats`` the error components of another message type."""
    ERROR_MODELS[model] = fn


def _col(msgs: Sequence[Any], name: str) -> np.ndarray:
    return np.array([math.nan if getattr(m, name) is None else getattr(m, name) for m in msgs], dtype=float)


def _speed_log(msgs: Sequence[Any], t: TruthState) -> dict[str, np.ndarray]:
    ve, vn, vu = t.velocity_mps[:, 0], t.velocity_mps[:, 1], t.velocity_mps[:, 2]
    h = t.heading_rad
    return {
        "v_forward_mps": _col(msgs, "v_forward_mps") - (ve * np.sin(h) + vn * np.cos(h)),
        "v_starboard_mps": _col(msgs, "v_starboard_mps") - (ve * np.cos(h) - vn * np.sin(h)),
        "v_down_mps": _col(msgs, "v_down_mps") + vu,
    }


def _heading(msgs: Sequence[Any], t: TruthState) -> dict[str, np.ndarray]:
    return {"heading_rad": wrap_pi_left(_col(msgs, "heading_rad") - t.heading_rad)}


def _attitude(msgs: Sequence[Any], t: TruthState) -> dict[str, np.ndarray]:
    return {
        "heading_rad": wrap_pi_left(_col(msgs, "heading_rad") - t.heading_rad),
        "pitch_rad": wrap_pi_left(_col(msgs, "pitch_rad") - t.pitch_rad),
        "roll_rad": wrap_pi_left(_col(msgs, "roll_rad") - t.roll_rad),
    }


def _depth(msgs: Sequence[Any], t: TruthState) -> dict[str, np.ndarray]:
    return {"depth_m": _col(msgs, "depth_m") + t.position_m[:, 2]}


def _ins(msgs: Sequence[Any], t: TruthState) -> dict[str, np.ndarray]:
    p, v = t.position_m, t.velocity_mps
    return {
        "x_m": _col(msgs, "x_m") - p[:, 1],
        "z_m": _col(msgs, "z_m") - p[:, 0],
        "h_m": _col(msgs, "h_m") - p[:, 2],
        "vx_mps": _col(msgs, "vx_mps") - v[:, 1],
        "vz_mps": _col(msgs, "vz_mps") - v[:, 0],
        "vh_mps": _col(msgs, "vh_mps") - v[:, 2],
    }


for _model, _fn in (
    (SpeedLog, _speed_log),
    (Heading, _heading),
    (Attitude, _attitude),
    (Depth, _depth),
    (InsSample, _ins),
):
    register_error_model(_model, _fn)


class InterpolatedTruth:
    """Truth of one platform by linear interpolation of its Truth messages (heading unwrapped)."""

    def __init__(self, truths: Sequence[Truth]) -> None:
        self.t = np.array([m.header.stamp_ns for m in truths], dtype=float)
        self.pos = np.array([m.position_m for m in truths], dtype=float)
        self.vel = np.array([m.velocity_mps or [math.nan] * 3 for m in truths], dtype=float)
        att = np.array([m.attitude_rad or [math.nan] * 3 for m in truths], dtype=float)
        self.att = np.column_stack([np.unwrap(att[:, 0]), att[:, 1], att[:, 2]])

    def truth_at(self, stamps_ns: np.ndarray) -> TruthState:
        s = np.asarray(stamps_ns, dtype=float)

        def interp(a: np.ndarray) -> np.ndarray:
            return np.column_stack([np.interp(s, self.t, a[:, j], left=math.nan, right=math.nan) for j in range(3)])

        att = interp(self.att)
        return TruthState(interp(self.pos), interp(self.vel), np.mod(att[:, 0], 2 * math.pi), att[:, 1], att[:, 2])


def _platform_of(key: str) -> str | None:
    parts = key.split("/")
    if len(parts) == 5 and parts[0] == keys.ROOT and parts[1] == "sensor":
        return parts[2]
    return None


def _stats(x: np.ndarray) -> dict[str, float | int | None]:
    x = x[np.isfinite(x)]
    n = int(x.size)
    if n == 0:
        return {"count": 0, "mean": None, "sd": None, "rms": None}
    return {
        "count": n,
        "mean": float(np.mean(x)),
        "sd": float(np.std(x, ddof=1)) if n > 1 else None,
        "rms": float(np.sqrt(np.mean(x * x))),
    }


def error_series(
    events: Iterable[Event], platforms: Mapping[str, TruthSource] | None = None
) -> dict[str, dict[str, Any]]:
    """Per sensor key: message type, stamps and the error array of each component (``measured - true``)."""
    sensors: dict[str, list[Event]] = defaultdict(list)
    truths: dict[str, list[Truth]] = defaultdict(list)
    for ev in events:
        if _platform_of(ev.key) is not None:
            sensors[ev.key].append(ev)
        elif isinstance(ev.msg, Truth):
            truths[ev.msg.platform].append(ev.msg)
    out: dict[str, dict[str, Any]] = {}
    for key in sorted(sensors):
        evs = sensors[key]
        msgs = [e.msg for e in evs]
        stamps = np.array([e.stamp_ns for e in evs], dtype=np.int64)
        platform = _platform_of(key) or ""
        model = type(msgs[0])
        entry: dict[str, Any] = {"type": model.__name__, "stamps_ns": stamps, "errors": {}}
        fn = ERROR_MODELS.get(model)
        source: TruthSource | None = (platforms or {}).get(platform)
        if source is None and len(truths.get(platform, [])) >= 2:
            source = InterpolatedTruth(truths[platform])
        if fn is not None and source is not None and all(type(m) is model for m in msgs):
            entry["errors"] = fn(msgs, source.truth_at(stamps))
        out[key] = entry
    return out


def sensor_stats(events: Iterable[Event], platforms: Mapping[str, TruthSource] | None = None) -> dict[str, Any]:
    """``{key: {"type", "count", "errors": {component: {count, mean, sd, rms}}}}`` for one run."""
    return {
        key: {
            "type": e["type"],
            "count": int(e["stamps_ns"].size),
            "errors": {c: _stats(v) for c, v in sorted(e["errors"].items())},
        }
        for key, e in error_series(events, platforms).items()
    }


def aggregate_sensor_stats(per_run: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Pool runs: total count, and mean/SD/RMS of all samples of all runs together."""
    out: dict[str, Any] = {}
    for key in sorted({k for run in per_run for k in run}):
        entries = [run[key] for run in per_run if key in run]
        comps: dict[str, Any] = {}
        for comp in sorted({c for e in entries for c in e["errors"]}):
            n = s1 = s2 = 0.0
            for e in entries:
                st = e["errors"].get(comp)
                if st and st["count"]:
                    n += st["count"]
                    s1 += st["count"] * st["mean"]
                    s2 += st["count"] * st["rms"] ** 2
            if n == 0:
                comps[comp] = {"count": 0, "mean": None, "sd": None, "rms": None}
                continue
            mean = s1 / n
            var = (s2 - n * mean * mean) / (n - 1) if n > 1 else None
            comps[comp] = {
                "count": int(n),
                "mean": mean,
                "sd": math.sqrt(max(var, 0.0)) if var is not None else None,
                "rms": math.sqrt(s2 / n),
            }
        out[key] = {"type": entries[0]["type"], "count": sum(e["count"] for e in entries), "errors": comps}
    return out
