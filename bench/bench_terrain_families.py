"""Reliability conditions over families of terrain, a new terrain every run, scored against the exact posterior.

``python -m bench.bench_terrain_families [--runs N] [--out FILE.json]`` prints one row per (family, preset):

* availability (a valid fix within 40 s of the start), fixes, false fixes (> 1 cell on either axis) with the
  Clopper-Pearson 95 % upper bound of the false-fix rate per fix, runs with a false fix, fixes > 1.5 cells;
* the exact posterior (:mod:`services.terrain_nav.posterior`, a batch computation independent of the
  filter bank) at every evaluation once C1 holds: share decisive (>= 99 % of the mass within one cell of
  its mode) and correct (mode within one cell of the truth), and the share of those in which C1-C4 issued a
  fix ("taken");
* horizontal NEES of the fixes (e^T Cov^-1 e, 2 dof; mean and share within the chi2(2) 95 % bound 5.99),
  split into fixes on straight legs and fixes whose window holds a turn;
* the vertical channel: share of fixes with |dh error| <= 3 sqrt(P_hh) (AT-15);
* what blocked: the verdicts before a run's first fix within 40 s by state (C1 ACQUIRING, C2 NO_FIX_FIT, C3
  NO_FIX_AMBIGUOUS, C4 NO_FIX_UNSTABLE: the first condition that failed), and at the decisive-and-correct
  evaluations not taken, the share with C2, C3, C4 false; first-fix times. ``--set KEY=JSON`` overrides a
  FlightScenario field of the selected families (the sweep of issue 16).

Families: Hurst exponent (roughness), rough terrain (H 0.35) with a 10-cell correlation length, 6 m relief or a
130 m/s flight (issue 16), von Karman correlation length, relief (RMS adjacent-cell change),
a low-relief map, a coarse partly flat map (2.4 km cells, mountains on one side and a plain on the other)
and a turning flight (waypoints). Presets: ``paper`` (the digest's §6) and ``robust`` (C3 floor, C3 evidence cap,
slope term, refinement, δh from the refinement's replay); a
preset may carry options after ``+``: ``robust+refine`` (``refine: true``), ``robust+mu2=0.5`` (JSON values).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import beta

from schemas.terrain_nav import TerrainFix, TerrainVerdict
from services.terrain_nav.config import TerrainNavConfig
from services.terrain_nav.core import TerrainNavigator
from services.terrain_nav.paths import MapWaypoint, waypoint_path
from services.terrain_nav.posterior import exact_posterior
from services.terrain_nav.simulation import FlightScenario, make_world, simulate_flight
from services.terrain_nav.worlds import coarse_partly_flat_world
from shared.errors import InputRejected

CHI2_2_95 = 5.991


@dataclass
class Family:
    name: str
    scenario: FlightScenario
    world: str = "synthetic"  # or "coarse_flat"
    turn: bool = False


FAMILIES = [
    Family("H 0.35 (rough)", FlightScenario(H=0.35)),
    # issue 16's rough-terrain availability (docs/terrain_nav.md, "Rough terrain: availability"): the sweep's points
    # where the paper's C3 withholds fixes the exact posterior already calls
    Family("rough, corr 10 cells", FlightScenario(H=0.35, corr_cells=10.0)),
    Family("rough, relief 6 m", FlightScenario(H=0.35, rms_inc_m=6.0)),
    Family("rough, 130 m/s", FlightScenario(H=0.35, speed_mps=130.0)),
    Family("H 0.6 (digest)", FlightScenario(H=0.6)),
    Family("H 0.85 (smooth)", FlightScenario(H=0.85)),
    Family("corr 10 cells", FlightScenario(corr_cells=10.0)),
    Family("relief 6 m", FlightScenario(rms_inc_m=6.0)),
    Family("low relief 3 m", FlightScenario(rms_inc_m=3.0)),
    Family(
        "coarse partly flat 2.4 km",
        FlightScenario(cell_m=2400.0, start_cell=(30, 55), rate_hz=2.0, sigma_da_mps2=1e-5),
        world="coarse_flat",
    ),
    Family("turning flight (waypoints)", FlightScenario(map_cells=(200, 200)), turn=True),
]


@dataclass
class Tally:
    runs: int = 0
    available: int = 0
    fixes: int = 0
    false: int = 0
    over_1_5: int = 0
    runs_false: int = 0
    worst: float = 0.0
    post_evals: int = 0
    post_decisive_correct: int = 0
    post_decisive_wrong: int = 0
    taken: int = 0
    nees_straight: list[float] = field(default_factory=list)
    nees_turn: list[float] = field(default_factory=list)
    vert_in: int = 0
    vert_err_full: list[float] = field(default_factory=list)
    # evaluations without a fix, by the verdict's state (the first condition that failed: C1 ACQUIRING, C2
    # NO_FIX_FIT, C3 NO_FIX_AMBIGUOUS, C4 NO_FIX_UNSTABLE), before the run's first fix and in the first 40 s
    blocked_by: dict[str, int] = field(default_factory=dict)
    # decisive-and-correct posterior evaluations that were not taken: how many had C2, C3, C4 false
    missed_c: dict[str, int] = field(default_factory=dict)
    runs_post_ok_40: int = 0  # runs whose posterior was decisive and correct at an evaluation within 40 s
    first_fix_s: list[float] = field(default_factory=list)

    def row(self) -> dict[str, Any]:
        ub = float(beta.ppf(0.975, self.false + 1, self.fixes - self.false)) if self.fixes > self.false else 1.0

        def nees(v: list[float]) -> dict[str, Any]:
            if not v:
                return {"n": 0}
            a = np.asarray(v)
            return {"n": len(v), "mean": float(a.mean()), "in95": float(np.mean(a <= CHI2_2_95))}

        missed = self.post_decisive_correct - self.taken

        return {
            "runs": self.runs,
            "availability": self.available / max(self.runs, 1),
            "fixes": self.fixes,
            "false_fixes": self.false,
            "false_rate_ub95": ub,
            "runs_with_false": self.runs_false,
            "over_1_5_cells": self.over_1_5,
            "worst_cells": self.worst,
            "posterior_evals": self.post_evals,
            "posterior_decisive_correct": self.post_decisive_correct / max(self.post_evals, 1),
            "posterior_decisive_wrong": self.post_decisive_wrong / max(self.post_evals, 1),
            "fix_when_posterior_decisive": self.taken / max(self.post_decisive_correct, 1),
            "blocked_before_first_fix": dict(self.blocked_by),
            "missed_decisive_by": {k: v / max(missed, 1) for k, v in self.missed_c.items()},
            "runs_posterior_ok_within_40s": self.runs_post_ok_40,
            "first_fix_s_median": float(np.median(self.first_fix_s)) if self.first_fix_s else None,
            "first_fix_s_p90": float(np.percentile(self.first_fix_s, 90)) if self.first_fix_s else None,
            "nees_straight": nees(self.nees_straight),
            "nees_turn": nees(self.nees_turn),
            "vertical_within_3sigma": self.vert_in / max(self.fixes, 1),
            "vertical_full_window_n": len(self.vert_err_full),
            "vertical_full_window_median_m": float(np.median(self.vert_err_full)) if self.vert_err_full else None,
            "vertical_full_window_p95_m": float(np.percentile(self.vert_err_full, 95)) if self.vert_err_full else None,
        }


def preset_config(preset: str) -> TerrainNavConfig:
    """``paper``, ``robust`` or a preset with options after ``+``: ``robust+refine`` (true), ``robust+mu2=0.5``."""
    name, *opts = preset.split("+")
    kv = [o.split("=", 1) if "=" in o else [o, "true"] for o in opts]
    return TerrainNavConfig.model_validate({"preset": name, **{k: json.loads(v) for k, v in kv}})


def turning_path(sc: FlightScenario, rng: np.random.Generator):  # type: ignore[no-untyped-def]
    """An L-shaped flight: 8 km north, a 90 deg right turn at 3 deg/s, 8 km east (map frame: x, z)."""
    c = sc.cell_m
    x0, z0 = (60 + rng.uniform()) * c, (60 + rng.uniform()) * c
    wps = [MapWaypoint(x0, z0), MapWaypoint(x0 + 8000.0, z0), MapWaypoint(x0 + 8000.0 + 3000.0, z0 + 9000.0)]
    return waypoint_path(wps, sc.speed_mps, 3.0, sc.rate_hz)


def family_flight(fam: Family, seed0: int, r: int):  # type: ignore[no-untyped-def]
    """Run ``r`` of family ``fam``: a new world and flight from ``SeedSequence([seed0, r])`` (world, flight and path
    streams), and the flight's messages; every bench that scores these families flies the same ones."""
    w_seq, f_seq, p_seq = np.random.SeedSequence([seed0, r]).spawn(3)
    sc = fam.scenario
    if fam.world == "coarse_flat":
        world = coarse_partly_flat_world(r, np.random.default_rng(w_seq))
    else:
        world = make_world(sc, np.random.default_rng(w_seq))
    path = turning_path(sc, np.random.default_rng(p_seq)) if fam.turn else None
    flight = simulate_flight(sc, world, np.random.default_rng(f_seq), path)
    return flight, list(flight.messages())


def run_family(
    fam: Family,
    runs: int,
    seed0: int,
    presets: list[str],
    on_run: Callable[[dict[str, Tally]], None] | None = None,
    posterior: bool = True,
) -> dict[str, dict[str, Any]]:
    """Score ``runs`` flights of ``fam`` with each preset; ``on_run`` sees the tallies after every run."""
    tallies = {p: Tally() for p in presets}
    for r in range(runs):
        flight, msgs = family_flight(fam, seed0, r)
        for preset in presets:
            score_run(flight, msgs, preset_config(preset), tallies[preset], fam.turn, posterior)
        if on_run is not None:
            on_run(tallies)
    return {p: t.row() for p, t in tallies.items()}


def navigator_outputs(nav: TerrainNavigator, msgs: Iterable[Any]) -> Iterator[Any]:
    """Every output of ``nav`` over ``msgs``, in order; an input the navigator rejects yields nothing. A generator:
    at each output, ``nav`` is as it stands right after the input that made it (its window, its map)."""
    for msg in msgs:
        try:
            out = nav.step(msg)
        except InputRejected:
            continue
        yield from out


def score_run(flight, msgs, cfg: TerrainNavConfig, t: Tally, turn: bool, posterior: bool = True) -> None:  # type: ignore[no-untyped-def]
    nav = TerrainNavigator(flight.world.ref_map, cfg)
    cell = flight.cell_m
    t.runs += 1
    errs = []
    first_fix = None
    first_post_ok = None
    horizon = 40.0 * (flight.cell_m / 125.0 if flight.cell_m > 125.0 else 1.0)
    for m in navigator_outputs(nav, msgs):
        if isinstance(m, TerrainFix):
            ts = m.header.stamp_ns * 1e-9
            d = flight.truth_at(ts)
            ex, ez = (m.dx_m - d["dx"]) / cell, (m.dz_m - d["dz"]) / cell
            e = max(abs(ex), abs(ez))
            errs.append(e)
            first_fix = ts if first_fix is None else first_fix
            err = np.array([m.dx_m - d["dx"], m.dz_m - d["dz"]])
            nees = float(err @ np.linalg.solve(np.array(m.estimate.covariance), err))
            win = nav.window.measq
            if turn:
                w = list(win)
                heading = [math.atan2(q.z_mean - p.z_mean, q.x_mean - p.x_mean) for p, q in itertools.pairwise(w)]
                turning = bool(heading) and (max(heading) - min(heading)) > math.radians(10.0)
            else:
                turning = False
            (t.nees_turn if turning else t.nees_straight).append(nees)
            dh = m.vertical.index("dh")
            if abs(m.vertical.mean[dh] - d["dh"]) <= 3.0 * math.sqrt(m.vertical.covariance[dh][dh]):
                t.vert_in += 1
            if m.verdict.n_valid >= m.verdict.n_max:
                t.vert_err_full.append(abs(m.vertical.mean[dh] - d["dh"]))
            continue
        if not isinstance(m, TerrainVerdict):
            continue
        state = m.state
        if (
            first_fix is None
            and state in ("ACQUIRING", "NO_FIX_FIT", "NO_FIX_AMBIGUOUS", "NO_FIX_UNSTABLE")
            and m.header.stamp_ns * 1e-9 - flight.t0_s <= horizon
        ):
            t.blocked_by[state] = t.blocked_by.get(state, 0) + 1
        if posterior and m.c1_enough_data and m.state != "RESET":
            post = exact_posterior(list(nav.window.measq), nav.map, cfg, nav.D1)
            newest = nav.window.measq[-1]
            d = flight.truth_at(newest.t)
            it = math.floor((newest.x_mean + d["dx"] - nav.map.x0_m) / cell) - newest.I
            jt = math.floor((newest.z_mean + d["dz"] - nav.map.z0_m) / cell) - newest.J
            i, j = post.argmax
            t.post_evals += 1
            if post.decisive():
                if max(abs(i - it), abs(j - jt)) <= 1:
                    t.post_decisive_correct += 1
                    t.taken += bool(m.valid)
                    if first_post_ok is None:
                        first_post_ok = newest.t
                    if not m.valid:
                        for c, ok in (("C2", m.c2_fit), ("C3", m.c3_unique), ("C4", m.c4_stable)):
                            t.missed_c[c] = t.missed_c.get(c, 0) + (not ok)
                else:
                    t.post_decisive_wrong += 1
    t.fixes += len(errs)
    nf = sum(e > 1.0 for e in errs)
    t.false += nf
    t.runs_false += nf > 0
    t.over_1_5 += sum(e > 1.5 for e in errs)
    t.worst = max([t.worst, *errs])
    if first_fix is not None:
        t.first_fix_s.append(first_fix - flight.t0_s)
    if first_fix is not None and first_fix - flight.t0_s <= horizon:
        t.available += 1
    if first_post_ok is not None and first_post_ok - flight.t0_s <= horizon:
        t.runs_post_ok_40 += 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.bench_terrain_families")
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--seed", type=int, default=16)
    ap.add_argument("--family", action="append", help="only families whose name starts with this")
    ap.add_argument("--preset", action="append", help="paper, robust, robust+refine, ... (default: paper and robust)")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        help="override a FlightScenario field of the selected families, KEY=JSON (e.g. rms_inc_m=6, speed_mps=100)",
    )
    ap.add_argument("--no-posterior", action="store_true", help="skip the exact posterior (5-10x faster)")
    ap.add_argument("--out", default=None, help="JSON file, rewritten after every run (a partial run is kept)")
    a = ap.parse_args(argv)
    out: dict[str, Any] = {}

    def dump() -> None:
        if a.out:
            with open(a.out, "w") as fh:
                json.dump(out, fh, indent=1)

    overrides = {k: json.loads(v) for k, v in (kv.split("=", 1) for kv in a.set)}
    for fam in FAMILIES:
        if a.family and not any(fam.name.startswith(f) for f in a.family):
            continue
        if overrides:
            sc = FlightScenario.model_validate({**fam.scenario.model_dump(), **overrides})
            fam = Family(f"{fam.name} {' '.join(a.set)}", sc, fam.world, fam.turn)
        t0 = time.time()

        def on_run(tallies: dict[str, Tally], name: str = fam.name) -> None:
            out[name] = {p: t.row() for p, t in tallies.items()}
            dump()

        out[fam.name] = run_family(fam, a.runs, a.seed, a.preset or ["paper", "robust"], on_run, not a.no_posterior)
        for preset, row in out[fam.name].items():
            print(
                f"{fam.name:28s} {preset:14s} avail {row['availability']:.3f} fixes {row['fixes']:5d} "
                f"false {row['false_fixes']:3d} (ub95 {row['false_rate_ub95']:.4f}, runs {row['runs_with_false']}, "
                f">1.5 {row['over_1_5_cells']}, worst {row['worst_cells']:.2f}) "
                f"post ok {row['posterior_decisive_correct']:.3f} "
                f"wrong {row['posterior_decisive_wrong']:.3f} taken {row['fix_when_posterior_decisive']:.3f} "
                f"NEES s {row['nees_straight']} t {row['nees_turn']} vert {row['vertical_within_3sigma']:.3f} "
                f"full-window median/p95 {row['vertical_full_window_median_m']}/{row['vertical_full_window_p95_m']} "
                f"blocked {row['blocked_before_first_fix']} missed-by {row['missed_decisive_by']} "
                f"post-ok<=40s {row['runs_posterior_ok_within_40s']} first fix median/p90 "
                f"{row['first_fix_s_median']}/{row['first_fix_s_p90']} "
                f"[{time.time() - t0:.0f}s]",
                flush=True,
            )
    dump()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
