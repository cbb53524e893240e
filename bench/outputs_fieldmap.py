"""Every field every compose service publishes, mapped to the Gaussian-block layout, hashed: old tree vs new tree.

Issue 19 item 6 moved each fix's and track's mean and covariance into one
:class:`~schemas.estimate.GaussianEstimate` block, so the bytes of those messages changed on purpose and
:mod:`bench.outputs_digest` cannot compare them. This script runs every ``fixstream run <service>`` of
``compose.yaml`` (the recorder aside) offline on a scenario, as ``outputs_digest`` does, unpacks what each one
publishes (the wire bytes, ``codec.encode``), rewrites a message of the old layout into the new one with
:data:`FIELD_MAP` (old fields → block paths; the block's frame, component names and units as the new code writes
them) and hashes the whole message (every field, canonical JSON, floats by their exact ``repr``; the schema id
too, with the version bump mapped). In the new tree nothing is rewritten. Old and new give the same digest per
service iff every published field, every number among them, is equal after the mapping. Run it with each tree
first on the path::

    cd /tmp/old && PYTHONPATH=/tmp/old python /path/to/new/bench/outputs_fieldmap.py scenarios/demo.yaml
    python -m bench.outputs_fieldmap scenarios/demo.yaml                   # in the new tree

``--service NAME`` restricts to compose services whose name starts with NAME; ``--env K=V`` overrides the
services' compose environment (e.g. ``FIXSTREAM_LBL_NAV_PLATFORM``), for scenarios whose platforms are not the
demo's. Each line: service, outputs, messages rewritten, numbers hashed, SHA-256, and the SHA-256 of what the
consumers make of the outputs: every :class:`~shared.foxglove.frames.Estimate` of
:func:`~shared.foxglove.frames.estimates_of` (the report's and Foxglove's input: position and covariance in
scenario ENU, validity, labels, extras), which the new generic block conversion must leave equal too.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np

from services.player.scenario import load_scenario
from shared import codec
from shared.foxglove.frames import FrameContext, estimates_of
from tools.report.offline import scenario_feed, service_outputs
from tools.stack import load_compose

_M3 = ["m", "m", "m"]
_MS3 = ["m/s", "m/s", "m/s"]
_XYZ = ["x", "y", "z"]

#: type name -> rules. A rule ``(where, new_field, mean, covariance, components, units, frame)`` builds the block
#: ``new_field`` in each object at ``where`` ("" the message, "tracks[]" each element of ``tracks``) from the old
#: fields: ``mean`` lists sources (``"f"``: the list field spread, ``"f[i]"``: one element, else a scalar field),
#: ``covariance`` names the old matrix field (None there: the block is None), ``frame`` is a format string on the
#: message (``{frame_id}``: its header's). A rule ``(where, new_field, source)`` moves one value. Old fields used
#: are removed.
FIELD_MAP: dict[str, list[tuple[Any, ...]]] = {
    "Fix": [
        ("", "estimate", ["position_m"], "position_cov_m2", _XYZ, _M3, "{frame_id}"),
        ("", "velocity", ["velocity_mps"], "velocity_cov_m2s2", ["vx", "vy", "vz"], _MS3, "{frame_id}"),
        ("hypotheses[]", "estimate", ["position_m"], "position_cov_m2", _XYZ, _M3, "{frame_id}"),
    ],
    "Track": [
        ("", "estimate", ["state"], "covariance", [*_XYZ, "vx", "vy", "vz"], [*_M3, *_MS3], "{frame_id}"),
    ],
    "LblFix": [
        ("", "estimate", ["position_m"], "position_cov_m2", _XYZ, _M3, "{frame_id}"),
        (
            "",
            "state",
            ["position_m[0]", "position_m[1]", "dc_mps", "dK_rad", "dU_north_mps", "dU_east_mps"],
            "state_cov",
            ["x", "y", "dc", "dK", "dU_north", "dU_east"],
            ["m", "m", "m/s", "rad", "m/s", "m/s"],
            "{frame_id}",
        ),
        ("hypotheses[]", "estimate", ["position_m"], "position_cov_m2", _XYZ, _M3, "{frame_id}"),
    ],
    "RdNavFix": [
        ("", "depth_m", "position_ned_m[2]"),
        ("", "estimate", ["position_ned_m[0]", "position_ned_m[1]"], "cov_xy_m2", ["x", "y"], ["m", "m"], "{frame_id}"),
    ],
    "TerrainFix": [
        ("", "estimate", ["x_corr_m", "z_corr_m"], "cov_xz_m2", ["x", "z"], ["m", "m"], "{frame_id}"),
        ("", "vertical", ["dvh_mps", "dh_m"], "cov_vert", ["dvh", "dh"], ["m/s", "m"], "{frame_id}"),
    ],
    "PclScanReport": [
        ("tracks[]", "estimate", ["state_enu"], "cov_enu", [*_XYZ, "vx", "vy", "vz"], [*_M3, *_MS3], "{frame_id}"),
        (
            "tracks[]",
            "bistatic",
            ["bistatic"],
            "bistatic_cov",
            ["r_b", "az", "el", "v_b"],
            ["m", "deg", "deg", "m/s"],
            "bistatic/{receiver_id}/{illuminator_id}",
        ),
    ],
    "AttitudeEstimate": [
        (
            "",
            "estimate",
            ["state"],
            "state_cov",
            ["x", "vx", "ax", "y", "vy", "ay", "z", "vz", "az"],
            ["m", "m/s", "m/s^2", "m", "m/s", "m/s^2", "m", "m/s", "m/s^2"],
            "{frame_id}",
        ),
    ],
}
#: schema version of each rewritten type after the change (the old tree's wire ids say 1)
NEW_VERSION = {name: 2 for name in FIELD_MAP}

_ITEM = re.compile(r"^(\w+)\[(\d+)\]$")


def _take(obj: dict[str, Any], src: str, used: set[str]) -> Any:
    m = _ITEM.match(src)
    if m:
        used.add(m[1])
        v = obj.get(m[1])
        return None if v is None else v[int(m[2])]
    used.add(src)
    return obj.get(src)


def _apply(msg: dict[str, Any], obj: dict[str, Any], rule: tuple[Any, ...], used: set[str]) -> None:
    if len(rule) == 3:
        obj[rule[1]] = _take(obj, rule[2], used)
        return
    _, field, mean_src, cov_src, comps, units, frame = rule
    cov = _take(obj, cov_src, used)
    mean: list[Any] = []
    for src in mean_src:
        v = _take(obj, src, used)
        mean.extend(v if isinstance(v, list) else [v])
    if cov is None:
        obj[field] = None
        return
    fmt = {"frame_id": msg["header"]["frame_id"], **{k: v for k, v in msg.items() if isinstance(v, str)}}
    obj[field] = {
        "frame": frame.format(**fmt),
        "components": list(comps),
        "units": list(units),
        "mean": mean,
        "covariance": cov,
    }


def to_new_layout(name: str, msg: dict[str, Any]) -> bool:
    """Rewrite ``msg`` (an unpacked message of type ``name``) from the old layout in place; True if it was old."""
    rules = FIELD_MAP.get(name, [])
    if not rules:
        return False
    old = False
    by_where: dict[str, list[tuple[Any, ...]]] = {}
    for r in rules:
        by_where.setdefault(r[0], []).append(r)
    for where, rs in by_where.items():
        objs = [msg] if where == "" else list(msg.get(where.removesuffix("[]"), []))
        for obj in objs:
            if rs[0][1] in obj and not (len(rs[0]) > 3 and rs[0][3] in obj):
                continue  # already the new layout
            used: set[str] = set()
            for r in rs:
                _apply(msg, obj, r, used)
            for u in used - {r[1] for r in rs}:
                obj.pop(u, None)
            old = True
    return old


def _plain(v: Any) -> Any:
    """JSON-able copy: arrays as lists (their float64 values exactly), numpy scalars as Python numbers."""
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_plain(x) for x in v]
    if isinstance(v, np.ndarray | np.generic):
        return _plain(v.tolist())
    return v


def _numbers(v: Any) -> int:
    if isinstance(v, dict):
        return sum(_numbers(x) for x in v.values())
    if isinstance(v, list):
        return sum(_numbers(x) for x in v)
    return int(isinstance(v, float | int) and not isinstance(v, bool))


def fieldmap_digests(
    scenario: Path,
    compose_file: Path = Path("compose.yaml"),
    only: str | None = None,
    env: dict[str, str] | None = None,
) -> dict[str, tuple[int, int, int, str, str]]:
    """Per compose service: (outputs, messages rewritten, numbers hashed, SHA-256 of the mapped messages, SHA-256
    of their estimates)."""
    sc = load_scenario(scenario)
    feed = scenario_feed(sc)
    ctx = FrameContext.from_scenario(sc)
    out: dict[str, tuple[int, int, int, str, str]] = {}
    for name, spec in load_compose(compose_file).services.items():
        cmd = list(spec.command or [])
        if len(cmd) < 3 or cmd[1] != "run" or cmd[2] == "recorder" or (only and not name.startswith(only)):
            continue
        outputs = service_outputs(name, feed, compose_file, env)
        h, he = hashlib.sha256(), hashlib.sha256()
        rewritten = numbers = 0
        for key, msg in outputs:
            for est in estimates_of(key, msg, ctx):
                he.update(json.dumps(_plain(est.__dict__), sort_keys=True, allow_nan=True).encode())
            obj = codec.unpack(codec.encode(msg))
            type_name = type(msg).__name__
            rewritten += to_new_layout(type_name, obj)
            version = NEW_VERSION.get(type_name, type(msg).schema_version)
            numbers += _numbers(obj)
            h.update(json.dumps([key, type_name, version, obj], sort_keys=True, allow_nan=True).encode())
        out[name] = (len(outputs), rewritten, numbers, h.hexdigest(), he.hexdigest())
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", nargs="?", default="scenarios/demo.yaml")
    ap.add_argument("--service", default=None, help="only compose services whose name starts with this")
    ap.add_argument("--env", action="append", default=[], help="K=V override of the services' environment")
    a = ap.parse_args(argv)
    env = dict(kv.split("=", 1) for kv in a.env)
    for name, (n, rw, nums, digest, est) in fieldmap_digests(Path(a.scenario), only=a.service, env=env).items():
        print(f"{name} {n} {rw} {nums} {digest} {est}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
