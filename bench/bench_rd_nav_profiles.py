"""RD-LBL navigation beyond the paper's case (issue 16): the held-out scenario files, Monte-Carlo, scored apart.

For every file (default: rd_hover, rd_hover_dvl_scale, rd_speed_profile, rd_weak_geometry, rd_group6,
rd_group6_digest_selection) and every rd_nav estimator it names: re-initialisations, NIS-gated cycles, PF |e| RMS /
max, and the NEES of the PF and the EKF shadow by motion regime (straight legs, manoeuvres = turns and speed changes,
hovering) against the chi-square band of the number of runs (:mod:`services.rd_nav.consistency`). For the group
files also the beacon set and leader the coordinator assigned and their single-cycle Cramer-Rao bound along the
movers' true tracks, computed here independently of the coordinator's own scoring (per point with
:mod:`services.rd_nav.geometry`: the full R of §4.2 with the sound-speed and motion-compensation terms).

    python -m bench.bench_rd_nav_profiles [--runs 10] [--seed 1] [--files rd_hover ...] [--workers 1]

(``python -m bench rd_nav_profiles`` runs the defaults; docs/rd_nav.md quotes --runs 20.)

Prints Markdown tables and one JSON line (``JSON {...}``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from schemas import Truth
from schemas.rd_nav import BeaconAssignment
from services.player.scenario import Scenario, load_scenario
from services.player.timeline import build, player_source, stamp
from services.rd_nav.geometry import crlb, jacobian_d, measurement_cov, motion_comp_cov
from shared import keys
from tools.montecarlo import jsonable, load_plugin

REPO = Path(__file__).resolve().parents[1]
FILES = [
    "rd_hover",
    "rd_hover_dvl_scale",
    "rd_speed_profile",
    "rd_weak_geometry",
    "rd_group6",
    "rd_group6_digest_selection",
]
SIGMA_T_S, SIGMA_C_MPS, SIGMA_V_MPS, C_MPS = 0.2e-3, 0.3, 0.05, 1500.0


def bound_m(p: np.ndarray, depth: float, a: BeaconAssignment) -> float:
    """Single-cycle CRLB DRMS at p of the assignment's ordered set (leader first), full R (§4.2, §4.6)."""
    pos = np.asarray(a.positions_ned_m, dtype=np.float64)
    if pos.shape[0] < 3:
        return math.inf
    leader, followers = pos[0], pos[1:]
    M = followers.shape[0]
    zj, delta = np.full(M, depth), np.zeros((M, 2))
    H = jacobian_d(p.reshape(1, 2), leader, followers, delta, depth, zj)[0]
    q = np.array([p[0], p[1], depth])
    rho1 = float(np.linalg.norm(q - leader))
    s = np.linalg.norm(followers - leader, axis=1) + np.linalg.norm(followers - q, axis=1) - rho1
    dt = np.asarray(a.tau_s[:M]) + s / C_MPS
    motion = motion_comp_cov(p, zj, delta, followers, dt, SIGMA_V_MPS)
    R = measurement_cov(s, C_MPS, SIGMA_T_S, 0.0, SIGMA_C_MPS, motion)
    try:
        return math.sqrt(float(np.trace(crlb(H, R))))
    except np.linalg.LinAlgError:
        return math.inf


def bounds_along_tracks(events: list[Any], movers: list[str]) -> dict[str, dict[str, float]]:
    """Per mover: the bound of the set in force at every 10 s truth sample while moving (RMS, max), and the sets."""
    out: dict[str, dict[str, Any]] = {}
    for auv in movers:
        akey, tkey = keys.sensor(auv, "nav", "assignment"), keys.truth(auv)
        current: BeaconAssignment | None = None
        vals: list[float] = []
        sets: set[str] = set()
        for ev in events:
            if ev.key == akey and isinstance(ev.msg, BeaconAssignment):
                current = ev.msg
                sets.add(" > ".join([current.leader_id, *current.follower_ids]))
            elif ev.key == tkey and isinstance(ev.msg, Truth) and current is not None:
                m = ev.msg
                if m.extra.get("moving", 0.0) < 0.5 or ev.stamp_ns % 10_000_000_000:
                    continue
                east, north, up = m.position_m
                vals.append(bound_m(np.array([north, east]), -up, current))
        v = np.asarray(vals)
        out[auv] = {
            "rms_m": float(np.sqrt(np.mean(v * v))) if v.size else math.nan,
            "max_m": float(v.max()) if v.size else math.nan,
            "sets": sorted(sets),
        }
    return out


def one_run(args: tuple[Scenario, int, int]) -> dict[str, Any]:
    scenario, seed, run = args
    sim = build(scenario, seed, run)
    events = list(stamp(sim.raw_events(), player_source("default")))
    res: dict[str, Any] = {"estimators": {}}
    for est in scenario.estimators:
        res["estimators"][est.instance] = load_plugin(est.kind).run_core(events, dict(est.params), scenario)
    movers = sorted({str(e.params.get("vehicle")) for e in scenario.estimators if e.kind == "rd_nav"})
    if any(e.kind == "coordinator" for e in scenario.estimators):
        res["bounds"] = bounds_along_tracks(events, movers)
    return jsonable(res)


def run_file(name: str, runs: int, seed: int, workers: int) -> dict[str, Any]:
    scenario = load_scenario(REPO / "scenarios" / f"{name}.yaml")
    t0 = time.perf_counter()
    tasks = [(scenario, seed, i) for i in range(runs)]
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            per_run = list(pool.map(one_run, tasks))
    else:
        per_run = [one_run(t) for t in tasks]
    agg: dict[str, Any] = {}
    for est in scenario.estimators:
        plugin = load_plugin(est.kind)
        agg[est.instance] = plugin.aggregate([r["estimators"][est.instance] for r in per_run])
    bounds: dict[str, Any] = {}
    for r in per_run:
        for auv, b in r.get("bounds", {}).items():
            d = bounds.setdefault(auv, {"rms2": [], "max": [], "sets": set()})
            d["rms2"].append(b["rms_m"] ** 2)
            d["max"].append(b["max_m"])
            d["sets"].update(b["sets"])
    return {
        "file": name,
        "runs": runs,
        "seed": seed,
        "wall_s": time.perf_counter() - t0,
        "aggregate": agg,
        "bounds": {
            a: {
                "rms_m": math.sqrt(float(np.mean(d["rms2"]))),
                "max_m": float(np.max(d["max"])),
                "sets": sorted(d["sets"]),
            }
            for a, d in bounds.items()
        },
    }


def _f(x: Any, nd: int = 2) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{nd}f}"


def tables(results: list[dict[str, Any]]) -> str:
    lines = [
        "| file | estimator | runs | re-inits | NIS-gated | PF RMS / max m | PF NEES straight / manoeuvre / hover "
        "(in band %) | EKF NEES straight / manoeuvre / hover | band (N runs) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        for inst, a in r["aggregate"].items():
            if "consistency" not in a:
                continue
            cells = []
            for est in ("pf", "ekf"):
                c = a["consistency"].get(est, {})
                parts = []
                for reg in ("straight", "manoeuvre", "hover"):
                    g = c.get(reg)
                    if g is None:
                        parts.append("-")
                    elif est == "pf":
                        parts.append(f"{_f(g['anees'])} ({_f(100 * g['in_band'], 0)})")
                    else:
                        parts.append(_f(g["anees"]))
                cells.append(" / ".join(parts))
            band = a["consistency"].get("pf", {}).get("band_n_runs") or [math.nan, math.nan]
            pf = a["pf"]
            lines.append(
                f"| {r['file']} | {inst} | {a['runs']} | {a['reinit_total']} | {a.get('nis_gated', 0)} | "
                f"{_f(pf['rms_m'])} / {_f(pf['max_m'])} | {cells[0]} | {cells[1]} | [{_f(band[0])}, {_f(band[1])}] |"
            )
    out = "\n".join(lines)
    grp = [r for r in results if r["bounds"]]
    if grp:
        rows = ["| file | mover | sets assigned (leader > followers) | bound RMS / max along the track m | PF RMS m |"]
        rows.append("|---|---|---|---|---|")
        for r in grp:
            for auv, b in r["bounds"].items():
                pf = r["aggregate"][auv]["pf"]["rms_m"]
                rows.append(
                    f"| {r['file']} | {auv} | {'; '.join(b['sets'])} | {_f(b['rms_m'])} / {_f(b['max_m'])} | {_f(pf)} |"
                )
        out += "\n\n" + "\n".join(rows)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--files", nargs="*", default=FILES)
    args = ap.parse_args([] if argv is None else argv)
    results = []
    for name in args.files:
        results.append(run_file(name, args.runs, args.seed, args.workers))
        print(f"{name}: {results[-1]['wall_s']:.0f} s", file=sys.stderr, flush=True)
    print(tables(results))
    slim = [{k: v for k, v in r.items()} for r in results]
    print("JSON " + json.dumps(jsonable(slim), default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
