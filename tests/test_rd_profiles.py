"""RD-LBL navigation beyond the paper's case (issue 16), small-N versions of bench/bench_rd_nav_profiles.py.

* **Hover**: an AUV stops inside the REF triangle and hovers 14 min with the digest's DR model (its 0.05 m/s
  Gauss-Markov speed error keeps acting at rest). Target: no re-initialisation, and the NEES of the PF and of the EKF
  shadow while hovering inside the 95 % band of the average over N runs, [chi2_2N(0.025), chi2_2N(0.975)] / N
  (Bar-Shalom's ANEES band; each epoch's average over the N independent runs is chi2_2N / N for a consistent filter,
  and averaging those over the epochs only narrows the spread, so the band is a necessary condition). Negative
  control: the filter before issue 16 (the digest's white q growing with distance) re-initialises while hovering
  (9 re-initialisations in 20 such runs when measured; P(none in 12 runs) < 1e-3 at that rate).
* **Six-vehicle group**: the coordinator's full-budget choice of set and leader against the digest's recipe, scored
  by the single-cycle Cramer-Rao bound along the movers' routes, computed here per point with the filters' geometry
  module (independent of the coordinator's vectorised scoring).

The full-size figures (40 runs x 2 h of each file) are in docs/rd_nav.md; ``@pytest.mark.slow`` runs them.
"""

from __future__ import annotations

import itertools
import math
from functools import lru_cache
from typing import Any

import numpy as np
import pytest
from conftest import REPO
from scipy.stats import chi2

from schemas.rd_nav import VehicleStatus
from services.coordinator.config import CoordinatorConfig
from services.coordinator.selection import select
from services.player.scenario import load_scenario
from services.rd_nav.config import RdNavConfig
from services.rd_nav.geometry import crlb, jacobian_d, measurement_cov, motion_comp_cov
from services.rd_nav.offline import run
from services.rd_nav.simulation import REF_BEACONS, VehicleSpec, ref
from tools.montecarlo import run_montecarlo

MC = {"propagated_fix_period_s": 0.0, "emit_propagated_after_cycle": False}
BEFORE = {"process_model": "paper", "outlier_only_if_gated": False}  # the filter before issue 16
HOVER_FROM_S = 100.0  # 150 m at 1.5 m/s, then hover
N_HOVER = 12


def band(n: int) -> tuple[float, float]:
    return float(chi2.ppf(0.025, 2 * n) / n), float(chi2.ppf(0.975, 2 * n) / n)


def hover_scenario(duration_s: float) -> Any:
    mover = VehicleSpec(auv_id="auv4", path=[(900.0, 1200.0), (1050.0, 1200.0)], hold_s=[0.0, 1e5])
    return ref(
        "inside",
        vehicles=[*(VehicleSpec(auv_id=a, start_node=n) for a, n in REF_BEACONS.items()), mover],
        duration_s=duration_s,
    )


@lru_cache(maxsize=2)
def hover_runs(config: tuple[tuple[str, Any], ...], runs: int) -> dict[str, Any]:
    core = RdNavConfig(n_particles=1000, **MC, **dict(config))
    scn = hover_scenario(960.0)
    per_epoch: dict[str, dict[int, list[float]]] = {"pf": {}, "ekf": {}}
    reinit = gated = 0
    for i in range(runs):
        log = run(scn, 7700 + i, core)
        c = log.cores["auv4"]
        reinit += c.reinit_count
        gated += c.counts.get("cycle_NIS_GATE", 0)
        for est, rows in (("pf", log.auv["auv4"].pf), ("ekf", log.auv["auv4"].ekf)):
            for t, x, y, qxx, qxy, qyy, tx, ty in rows:
                if t < HOVER_FROM_S + 60.0:  # hovering, and past the start
                    continue
                e = np.array([x - tx, y - ty])
                Q = np.array([[qxx, qxy], [qxy, qyy]])
                per_epoch[est].setdefault(round(t / 10.0), []).append(float(e @ np.linalg.solve(Q, e)))
    anees = {est: float(np.mean([np.mean(v) for v in d.values()])) for est, d in per_epoch.items()}
    return {"reinit": reinit, "gated": gated, "anees": anees, "epochs": len(per_epoch["pf"])}


def test_hovering_auv_keeps_lock_and_its_nees_band() -> None:
    res = hover_runs((), N_HOVER)
    lo, hi = band(N_HOVER)  # [1.31, 2.87] for 12 runs
    assert res["reinit"] == 0, res
    # NIS gate at chi2_0.999: a consistent filter gates 0.1 % of its ~80 x 12 cycles, mean ~1; P(more than 6) < 1e-3
    assert res["gated"] <= 6, res
    for est in ("pf", "ekf"):
        assert lo <= res["anees"][est] <= hi, (est, res)


def test_hover_negative_control_the_filter_before_issue_16_loses_lock() -> None:
    res = hover_runs(tuple(BEFORE.items()), N_HOVER)
    assert res["reinit"] > 0, res


# ------------------------------------------------------------------------------------------ group of six ----
GROUP6 = load_scenario(REPO / "scenarios" / "rd_group6.yaml")


def _group6() -> tuple[dict[str, np.ndarray], np.ndarray]:
    params = GROUP6.simulators[0].params
    nodes = {f"auv{k}": np.array(params["nodes"][f"n{k}"], dtype=np.float64) for k in range(1, 5)}
    pts = []
    for v in params["vehicles"]:
        if "path" in v:
            wp = np.array(v["path"], dtype=np.float64)
            for a, b in itertools.pairwise(wp):
                for f in np.linspace(0.0, 1.0, 9):
                    pts.append([*(a + f * (b - a)), 80.0])
    return nodes, np.array(pts)


def crlb_drms(p: np.ndarray, members: tuple[str, ...], nodes: dict[str, np.ndarray], tau: list[float]) -> float:
    """Single-cycle CRLB DRMS at p, full R of §4.2 (sigma_t 0.2 ms, sigma_c 0.3 m/s, sigma_v 0.05 m/s), per point."""
    leader, followers = nodes[members[0]], np.array([nodes[m] for m in members[1:]])
    zj, delta = np.full(len(members) - 1, 80.0), np.zeros((len(members) - 1, 2))
    H = jacobian_d(p[:2].reshape(1, 2), leader, followers, delta, 80.0, zj)[0]
    s = np.linalg.norm(followers - leader, axis=1) + np.linalg.norm(followers - p, axis=1) - np.linalg.norm(p - leader)
    R = measurement_cov(
        s, 1500.0, 0.2e-3, 0.0, 0.3, motion_comp_cov(p[:2], zj, delta, followers, np.array(tau) + s / 1500.0, 0.05)
    )
    return math.sqrt(float(np.trace(crlb(H, R))))


def test_group_of_six_leader_and_set_by_the_full_error_budget() -> None:
    """Four docked beacons, two movers 1.0-1.9 km beyond n3. The digest's recipe (arrival-time GDOP, shortest
    cycle) and the full-budget choice; the route's worst single-cycle bound of each, computed independently per point,
    must favour the full-budget choice by at least 30 % (it minimises exactly that quantity, up to the route sampling);
    the digest's choice is optimal for its own criterion (the arrival-time-only GDOP, leader-invariant)."""
    nodes, pts = _group6()
    tau = [0.5, 3.5]
    old = select(nodes, pts, None, CoordinatorConfig(cost_model="arrival_time"), 2)
    new = select(nodes, pts, None, CoordinatorConfig(), 2)
    assert old is not None and new is not None
    worst = {name: max(crlb_drms(p, s.members, nodes, tau) for p in pts) for name, s in (("old", old), ("new", new))}
    assert worst["new"] <= 0.7 * worst["old"], (old.members, new.members, worst)
    assert new.cost_m == pytest.approx(worst["new"], rel=0.05)  # the coordinator's own figure, same quantity
    # the leader matters: another leader for the digest's own set is better too
    alt = min(
        max(crlb_drms(p, (lead, *[m for m in old.members if m != lead]), nodes, tau) for p in pts)
        for lead in old.members
    )
    assert alt < worst["old"]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["rd_hover", "rd_hover_dvl_scale", "rd_speed_profile", "rd_weak_geometry"])
def test_profile_files_full_size(name: str) -> None:
    """40 runs x 2 h of each file: no re-initialisation; NEES of PF and EKF in the 40-run band in every regime."""
    sc = load_scenario(REPO / "scenarios" / f"{name}.yaml")
    res = run_montecarlo(sc, 40, 1, workers=2, progress=False)
    lo, hi = band(40)
    agg = res["aggregate"]["estimators"]["auv4"]
    assert agg["reinit_total"] == 0, agg["reinit_per_run"]
    for est in ("pf", "ekf"):
        for reg, c in agg["consistency"][est].items():
            if isinstance(c, dict):
                assert lo <= c["anees"] <= hi, (name, est, reg, c)


def test_vehicle_status_of_the_group_files_name_their_planned_routes() -> None:
    """The coordinator plans on the DEPARTED routes: the movers of rd_group6 announce theirs."""
    from services.player.timeline import build

    sim = build(GROUP6.model_copy(update={"duration_s": 5.0}), 1, 0)
    deps = [e.msg for e in sim.raw_events() if isinstance(e.msg, VehicleStatus) and e.msg.event == "DEPARTED"]
    assert {d.auv_id for d in deps} == {"auv5", "auv6"}
    assert all(len(d.planned_route_ned_m) >= 3 for d in deps)
