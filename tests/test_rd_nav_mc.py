"""``fixstream mc`` on the group-navigation scenarios (issue 5): the rd_nav and coordinator plugins.

Default run: the demo through the CLI with 1 and 2 workers (identical JSON); the metrics of the service's
published outputs equal ``run_core``'s (so ``fixstream report`` and ``fixstream mc`` agree); and T-ROB-1 with its
negative control, T-NOM-7 and T-ROB-8 through the scenario file ``rd_ref_inside_variants.yaml`` shortened to 1 h
(paired: the five filter configurations score the same simulated run). The digest's full counts through the
scenario files are behind ``@pytest.mark.slow`` (``make bench``-sized; the core-level acceptance tests with the
standard-error reasoning are ``test_rd_nav_nominal.py`` / ``test_rd_nav_robustness.py``).
"""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path
from typing import Any

import pytest
from conftest import REPO, fixstream_cmd
from stack_support import delivered, framed
from test_rd_nav_service import demo

from services.player.scenario import load_scenario
from services.player.simulators import Event
from services.rd_nav import mc as rd_mc
from services.rd_nav.service import RdNavService, RdNavSettings
from tools.montecarlo import jsonable, run_montecarlo, run_once

SCENARIOS = REPO / "scenarios"


def test_mc_is_the_same_for_one_and_two_workers(tmp_path: Path) -> None:
    outs = []
    for workers in (1, 2):
        out = tmp_path / f"w{workers}.json"
        cmd = ["mc", "rd_demo", "--runs", "2", "--seed", "3", "--workers", str(workers), "--out", str(out)]
        done = subprocess.run(
            fixstream_cmd(*cmd, "--no-progress"), cwd=REPO, capture_output=True, text=True, timeout=300
        )
        assert done.returncode == 0, done.stderr[-3000:]
        outs.append(out.read_text())
    assert outs[0] == outs[1]
    result = json.loads(outs[0])
    agg = result["aggregate"]["estimators"]
    assert set(agg) == {"auv4", "auv3", "group1"}
    assert agg["auv4"]["runs"] == 2 and agg["auv4"]["pf"]["n"] >= 2 * 7 and agg["auv4"]["pf"]["rms_m"] < 2.5
    assert agg["auv3"]["pf"]["n"] >= 2 * 4
    assert agg["group1"]["grants"] == 2 and agg["group1"]["grants_with_too_few_others"] == 0
    assert agg["group1"]["assigned_non_beacons"] == 0 and agg["group1"]["epochs_increasing"]
    run0 = result["per_run"][0]["estimators"]["auv4"]
    assert run0["rejected_cycles"] == {"NO_VALID_FOLLOWER": 1}  # the cycle in flight at the role swap
    assert set(run0) >= {"pf", "pf_summary", "ekf_summary", "reinit_count", "rejected_inputs", "status"}


def test_metrics_of_published_outputs_equal_run_core() -> None:
    scenario, events = demo()
    feed = framed(scenario, [(e.key, e.msg) for e in events])
    for auv in ("auv4", "auv3"):
        svc = RdNavService(RdNavSettings(instance=auv))
        out = svc.run_offline(delivered(svc, feed))
        outputs = [Event(o.msg.header.stamp_ns, o.key, o.msg) for o in out]  # diagnostics too: ignored
        params = {"vehicle": auv}
        published = jsonable(rd_mc.run_metrics(outputs, list(events), params, scenario))
        core = jsonable(rd_mc.run_core(list(events), params, scenario))
        assert set(core) - set(published) == set(rd_mc.OFFLINE_ONLY)
        assert published == {k: v for k, v in core.items() if k not in rd_mc.OFFLINE_ONLY}
    assert core["rejected_inputs"] == {"no_leader": 2}  # auv3: replies of the cycle in flight when it undocked
    # the only moving AUV is the default vehicle; two are ambiguous
    with pytest.raises(ValueError, match=r"name one in params\.vehicle"):
        rd_mc.run_core(list(events), {}, scenario)
    with pytest.raises(ValueError, match=r"config\.auv_id"):
        rd_mc.Params.model_validate({"config": {"auv_id": "x"}})
    with pytest.raises(ValueError, match="n_particles"):
        rd_mc.Params.model_validate({"config": {"n_particles": 1}})


def test_variants_through_the_plugin_t_rob_1_t_nom_7_t_rob_8() -> None:
    """One hour of REF inside (360 cycles, paired): compensation on <= 0.70 m, off > 3 m (T-ROB-1's negative
    control); N = 300 within +5 % of N = 1000 (T-NOM-7); undersized q with gating and re-initialisation <= 1.0 m,
    max <= 8 m, re-initialisations reported (T-ROB-8); none in the nominal run (T-NOM-8)."""
    sc = load_scenario(SCENARIOS / "rd_ref_inside_variants.yaml").model_copy(update={"duration_s": 3600.0})
    est = run_once(sc, 7, 0)["estimators"]
    rms = {k: v["pf_summary"]["rms_m"] for k, v in est.items()}
    assert est["auv4"]["scored"] >= 350
    assert rms["auv4"] <= 0.70 and est["auv4"]["reinit_count"] == 0, rms
    assert rms["auv4-no-motion-comp"] > 3.0, rms
    assert rms["auv4-n300"] <= 1.05 * rms["auv4"], rms
    small = est["auv4-small-q"]
    assert rms["auv4-small-q"] <= 1.0 and small["pf_summary"]["max_m"] <= 8.0 and small["reinit_count"] > 0, rms
    # (without gating and re-initialisation a loss of lock is a matter of time, not of every hour: the slow set
    # checks that variant over the file's 4 h runs)
    assert est["auv4"]["pf_summary"]["max_m"] < 10.0  # T-NOM-8 visual zone


def test_coordinator_plugin_on_the_fleet_hour() -> None:
    """T-CO-1/T-CO-3 on the closed-loop fleet (1 h, in-process): grants only with >= 3 other beacons, only
    docked beacons assigned, epochs increasing, never fewer than 3 beacons once the preliminary phase ended."""
    sc = load_scenario(SCENARIOS / "rd_fleet.yaml")
    res = run_once(sc, 1, 0)["estimators"]
    co = res["group1"]
    assert len(co["grants"]) >= 2 and co["grants_with_too_few_others"] == 0
    assert co["assigned_non_beacons"] == 0 and co["epochs_increasing"] and co["fewest_beacons_after_preliminary"] >= 3
    assert co["refused"] == {}
    for auv in ("auv1", "auv3"):
        pf = res[auv]["pf_summary"]
        assert res[auv]["scored"] >= 50 and pf["rms_m"] < 2.0 and pf["max_m"] < 10.0, (auv, pf)


def _loss_run_3(**config: Any) -> dict[str, Any]:
    """Run 3 of rd_rob_loss (seed 1) up to 6,300 s, with ``config`` over the file's estimator configuration."""
    sc = load_scenario(SCENARIOS / "rd_rob_loss.yaml")
    est = sc.estimators[0]
    params = {**est.params, "config": {**est.params.get("config", {}), **config}}
    sc = sc.model_copy(update={"duration_s": 6300.0, "estimators": [est.model_copy(update={"params": params})]})
    res: dict[str, Any] = run_once(sc, 1, 3)["estimators"]["auv4"]
    return res


def test_loss_excursion_is_followed() -> None:
    """T-ROB-4's hardest stretch at the file's seed: in run 3 a 3-sigma DR velocity excursion (~0.2 m/s) meets a run
    of lost packets at 5,900-6,100 s. The digest's limit, max <= 12 m, must hold there; the negative control (the
    digest's fixed q and 5 m re-seed rule over consecutive cycles only) must break it, or this test shows nothing."""
    run = _loss_run_3()
    assert run["pf_summary"]["max_m"] <= 12.0, run["pf_summary"]
    old = _loss_run_3(  # the digest's filter: white q, fixed re-seed rule, and none of issue 16's robustness rules
        process_model="paper",
        q_drift_mps=0.0,
        reinit_drift_sigma=0.0,
        reinit_strict_chain=True,
        outlier_only_if_gated=False,
        roughening_shrink=False,
        degenerate_neff_fraction=0.0,
        gate_after_updates=0,
    )
    assert old["pf_summary"]["max_m"] > 12.0, old["pf_summary"]


# ------------------------------------------------------------------------------ full counts (slow) ------------
#: scenario file -> (runs, checks on the pooled PF figures): the digest's limits (§6.3-§6.4)
FULL: dict[str, tuple[int, dict[str, float]]] = {
    "rd_ref_inside": (10, {"mean": 0.25, "sd_x": 0.75, "sd_y": 0.75, "rms": 0.70, "p99": 1.6, "max": 3.0}),
    "rd_ref_boundary": (10, {"mean": 0.25, "sd_x": 0.75, "sd_y": 0.75, "rms": 0.80, "p99": 2.0, "max": 4.0}),
    "rd_ref_outside": (10, {"mean": 0.25, "sd_x": 1.3, "sd_y": 0.6, "rms": 1.4, "p99": 3.8, "max": 8.0}),
    "rd_low_inside": (5, {"mean": 0.25, "sd_x": 0.75, "sd_y": 0.75, "rms": 0.5, "max": 2.0}),
    "rd_low_boundary": (5, {"mean": 0.25, "sd_x": 0.75, "sd_y": 0.75, "rms": 0.5, "max": 2.0}),
    "rd_low_outside": (5, {"mean": 0.25, "sd_x": 0.75, "sd_y": 0.75, "rms": 0.9, "p99": 2.5, "max": 5.0}),
    "rd_rob_multipath": (5, {"rms": 1.0, "p99": 3.5, "max": 15.0}),
    "rd_rob_multipath_outside": (5, {"rms": 1.6, "p99": 4.5, "max": 20.0}),
    "rd_rob_loss": (5, {"rms": 1.1, "p99": 3.7, "max": 12.0}),
    "rd_rob_clock_skew": (5, {"mean": 0.15, "rms": 0.70}),
    "rd_rob_node_errors": (10, {"rms": 1.3, "max": 5.0}),
    "rd_rob_follower_jitter": (5, {"rms": 0.75}),
    "rd_rob_racetrack": (5, {"rms": 10.0, "max": 40.0}),
}


def _check(p: dict[str, Any], limits: dict[str, float]) -> None:
    names = {"sd_x": "sd_x_m", "sd_y": "sd_y_m", "rms": "rms_m", "p99": "p99_m", "max": "max_m"}
    for k, lim in limits.items():
        if k == "mean":
            assert abs(p["mean_x_m"]) <= lim and abs(p["mean_y_m"]) <= lim, p
        else:
            assert p[names[k]] <= lim, (k, p)


#: scenario files known to miss the digest at seed 1: none. rd_rob_loss (T-ROB-4) missed until the correlated-drift
#: process noise (q_drift_mps) and the span-dependent re-seed tolerance (test_loss_excursion_is_followed keeps that
#: run as a regression case); rd_rob_racetrack (T-ROB-12) until weakly conditioned cycles stopped resetting the drift
#: growth (q_drift_weak_geometry; test_rd_nav_robustness.py has the default-run check).
KNOWN_FAILURES: set[str] = set()


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",
    [
        pytest.param(n, marks=pytest.mark.xfail(strict=True, reason="known miss at seed 1, see KNOWN_FAILURES"))
        if n in KNOWN_FAILURES
        else n
        for n in sorted(FULL)
    ],
)
def test_scenario_files_meet_the_digest(name: str) -> None:
    runs, limits = FULL[name]
    res = run_montecarlo(load_scenario(SCENARIOS / f"{name}.yaml"), runs, seed=1, progress=False)
    agg = res["aggregate"]["estimators"]["auv4"]
    _check(agg["pf"], limits)
    if name.startswith(("rd_ref_", "rd_low_")):
        assert 0.8 <= agg["pf"]["consistency"] <= (1.25 if name.startswith("rd_ref_") else 1.3), agg["pf"]
        assert agg["reinit_total"] == 0  # T-NOM-8
        assert agg["pf"]["max_m"] < 10.0


def _pf_fixes(name: str, run: int, **config: Any) -> list[tuple[str, float, float, float]]:
    """(kind, t s, |e| m, sqrt tr Q m) of the PF fixes of run ``run`` of a scenario file (seed 1): the vehicle's
    events through the core (run_core's path), with ``config`` over the file's estimator configuration."""

    from services.player.timeline import build, player_source, stamp
    from services.rd_nav.core import RdNavCore
    from services.rd_nav.service import fix_key, output_key

    sc = load_scenario(SCENARIOS / f"{name}.yaml")
    events = list(stamp(build(sc, 1, run).raw_events(), player_source("default")))
    params = dict(sc.estimators[0].params)
    params["config"] = {**params.get("config", {}), **config}
    core = RdNavCore(rd_mc.Params.model_validate(params).core_config("auv4"))
    track = rd_mc._TruthTrack([e.msg for e in events if e.key == "fixstream/truth/auv4"])  # type: ignore[misc]
    out = []
    for ev in events:
        if not ev.key.startswith("fixstream/sensor/auv4/"):
            continue
        for m in core.step(ev.msg):
            if output_key("auv4", m) == fix_key("auv4"):
                n, e = track.at(m.header.stamp_ns) or (math.nan, math.nan)
                q = m.estimate.covariance  # type: ignore[attr-defined]
                x, y = m.estimate.mean  # type: ignore[attr-defined]
                out.append((m.kind, m.header.stamp_ns * 1e-9, math.hypot(x - n, y - e), math.sqrt(q[0][0] + q[1][1])))  # type: ignore[attr-defined]
    return out


@pytest.mark.slow
def test_scenario_files_blackout_clock_step_and_c_bias() -> None:
    """T-ROB-5 (600 s blackout: uncertainty grows, recovery), T-ROB-6 (the clock step costs one cycle per run, no
    re-initialisation), T-ROB-11 (+1.5 m/s sound-speed bias: north bias 2.1 +- 0.4 m)."""
    step = run_montecarlo(load_scenario(SCENARIOS / "rd_rob_clock_step.yaml"), 5, seed=1, progress=False)
    agg = step["aggregate"]["estimators"]["auv4"]
    assert agg["rejected_cycles"].get("CLOCK_JUMP") == 5 and agg["reinit_total"] == 0 and agg["pf"]["rms_m"] <= 0.7
    bias = run_montecarlo(load_scenario(SCENARIOS / "rd_rob_c_bias.yaml"), 5, seed=1, progress=False)
    assert abs(bias["aggregate"]["estimators"]["auv4"]["pf"]["mean_x_m"] - 2.1) <= 0.4
    within_10 = 0
    for run in range(5):
        fixes = _pf_fixes("rd_rob_blackout", run, propagated_fix_period_s=10.0)
        prop = [f for f in fixes if f[0] == "PROPAGATED" and f[1] <= 4200.0]
        assert prop[-1][3] >= 10.0, prop[-1]  # reported sqrt tr Q at the end of the blackout
        after = [f[2] for f in fixes if f[0] == "CYCLE" and f[1] > 4200.0]
        to_1p5 = next(i for i, e in enumerate(after) if e < 1.5)
        assert to_1p5 <= 40 and max(after[30:]) <= 3.0, (run, to_1p5, max(after[30:]))
        within_10 += to_1p5 <= 10
    assert within_10 >= 4  # the digest's >= 80 % of runs
