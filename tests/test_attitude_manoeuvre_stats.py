"""Statistics of the default (manoeuvre) preset against preset paper on the project's manoeuvring flights (issue 15).

Small-N versions run by default; the full-size figures (100 runs per file, every file of the family) come from
``bench/bench_attitude_manoeuvre.py`` and are in docs/attitude.md; ``-m slow`` runs the whole family at N = 20.
Both presets see the same plots (``fixstream mc``'s run seeds: common random numbers), so a comparison of the
two is paired and much tighter than either figure alone.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from conftest import REPO

from services.attitude.config import CA_MODELS
from services.attitude.flights import FILES
from services.attitude.metrics import phase_table
from services.attitude.offline import evaluation_config, run_monte_carlo
from services.player.scenario import load_scenario
from tools.montecarlo import run_montecarlo

SCENARIOS = REPO / "scenarios"


#: the default preset with the model bank it had before the coordinated-turn model (issue 15, first round)
CA_BANK: dict[str, Any] = {"preset": "manoeuvre", "imm_models": [m.model_dump(mode="json") for m in CA_MODELS]}


def family_run(names: list[str], preset: str | dict[str, Any], runs: int) -> tuple[dict[str, Any], dict[str, int]]:
    """Pooled phase table and summed core counters of the scenario files ``names`` with ``preset`` (a preset name
    or a configuration)."""
    parts: list[dict[str, Any]] = []
    core: dict[str, int] = {}
    config = {"preset": preset} if isinstance(preset, str) else preset
    for name in names:
        sc = load_scenario(SCENARIOS / f"{name}.yaml")
        est = sc.estimators[0]
        params = {**dict(est.params), "reference": False, "config": config}
        sc = sc.model_copy(update={"estimators": [est.model_copy(update={"params": params})]})
        agg = run_montecarlo(sc, runs, seed=1, workers=1, progress=False)["aggregate"]["estimators"][est.instance]
        parts += agg["phase_samples"]
        for k, n in agg["core"].items():
            core[k] = core.get(k, 0) + int(n)
    return phase_table(parts), core


def valid_within_2sigma(table: dict[str, Any], angle: str = "psi") -> tuple[float, int]:
    """Fraction of VALID estimates (all phases) whose error is within 2 sigma, and their number."""
    n = inside = 0.0
    for row in table.values():
        v = row["valid"][angle]
        if v["share"] and v["within_2sigma"] is not None:
            k = v["share"] * row["samples"]
            n += k
            inside += v["within_2sigma"] * k
    return inside / n, round(n)


def binomial_lower(p: float, n: int, z: float = 3.0) -> float:
    """p - z sqrt(p (1 - p) / n): the 3-sigma lower bound of a binomial fraction of n draws."""
    return p - z * math.sqrt(p * (1.0 - p) / n)


def check_family(names: list[str], runs: int, turn_ratio_max: float) -> None:
    default, core_d = family_run(names, "manoeuvre", runs)
    paper, core_p = family_run(names, "paper", runs)
    # the gate does not fight manoeuvres: no plot gated, no reset; the paper preset's gate resets in turns
    assert core_d.get("innovation_gate", 0) == 0 and core_d.get("reset_nis", 0) == 0, core_d
    assert core_p.get("reset_nis", 0) > 0, core_p
    # turns: heading, and the LOS heading, much better than the paper filter's (paired, common random numbers)
    for angle in ("psi", "psi_los"):
        d, p = default["turn"]["rms_deg"][angle], paper["turn"]["rms_deg"][angle]
        assert d <= turn_ratio_max * p, (angle, d, p)
    # straight flight no worse than the paper filter's: heading and pitch on every straight leg (after the start
    # transient), and heading, pitch and roll on steady legs (30 s after a manoeuvre). The roll of the first
    # 30 s after a turn is not asserted: there both filters are still settling (docs: the full-size figures)
    for phase, angles in (("straight", ("psi", "theta")), ("steady", ("psi", "theta", "gamma"))):
        for angle in angles:
            d, p = default[phase]["rms_deg"][angle], paper[phase]["rms_deg"][angle]
            assert d <= p, (phase, angle, d, p)
    # NEES: the paper filter is off by orders of magnitude in turns (the issue: 40-460); the IMM's ANEES is
    # optimistic in turns by a factor ~2 (N = 50: 15.8 pooled, 15.0 light turns, 8.5 transport; light turns at
    # N = 3: 12.8-17.9 over seeds 1-5) and conservative on straight legs by a factor 2-3 (N = 50: 4.0): the
    # manoeuvre models' share of the mixture (docs: the full-size band figures and why)
    assert paper["turn"]["nees"]["anees_mean"] > 30.0
    assert 4.5 <= default["turn"]["nees"]["anees_mean"] <= 20.0, default["turn"]["nees"]
    assert 2.5 <= default["straight"]["nees"]["anees_mean"] <= 9.0, default["straight"]["nees"]
    # VALID means what it says: a consistent sigma puts 95.4 % of Gaussian errors within 2 sigma; the share of
    # VALID estimates within 2 sigma must not fall below the binomial 3-sigma bound of that (conservative is fine)
    frac, n = valid_within_2sigma(default)
    assert n >= 100 and frac >= binomial_lower(0.954, n), (frac, n)
    frac_p, n_p = valid_within_2sigma(paper)
    assert frac_p < binomial_lower(0.954, n_p), (frac_p, n_p)  # the paper filter's VALID is not (the issue)
    # the heading is defined on straight legs (the issue: undefined on 34-66 % of a slow aircraft's scans)
    assert default["straight"]["defined"]["psi"] >= 0.95


def test_light_aircraft_turns_default_against_paper() -> None:
    """Six light aircraft (75-120 m/s, 15-45 deg bank) x 3 runs per preset. The turn bound 0.8 is the full-size
    ratio (0.6 at N = 100, bench) plus the paired comparison's spread at N = 3 (0.55-0.65 over seeds 1-5)."""
    check_family(["attitude_turns_light"], runs=3, turn_ratio_max=0.8)


def test_light_aircraft_turns_ct_bank_against_the_ca_bank() -> None:
    """The default bank (straight, coordinated turn, onset) against the bank it replaced (Singer straight, CA
    manoeuvre, CA onset), paired on the same plots: six light aircraft x 3 runs. Over seeds 1-5 at this N the
    default was better in every row below (turn heading by 3-12 %, turn ANEES 12.8-17.9 against 16.8-20.6,
    straight and steady heading, pitch and roll), so the bounds are the plain comparisons."""
    ct, core_ct = family_run(["attitude_turns_light"], "manoeuvre", 3)
    ca, _ = family_run(["attitude_turns_light"], CA_BANK, 3)
    assert core_ct.get("innovation_gate", 0) == 0 and core_ct.get("reset_nis", 0) == 0, core_ct
    assert ct["turn"]["rms_deg"]["psi"] < ca["turn"]["rms_deg"]["psi"]
    a_ct, a_ca = ct["turn"]["nees"]["anees_mean"], ca["turn"]["nees"]["anees_mean"]
    assert abs(a_ct - 9.0) < abs(a_ca - 9.0), (a_ct, a_ca)
    for phase in ("straight", "steady"):
        for angle in ("psi", "theta", "gamma"):
            assert ct[phase]["rms_deg"][angle] <= ca[phase]["rms_deg"][angle], (phase, angle)


def test_default_is_no_worse_than_paper_on_the_papers_straight_flight() -> None:
    """The digest's §3.1 flight (9S15), 40 runs of each preset on the same plots: the default preset's LOS-angle
    RMS over scans 21-100 is no larger than the paper filter's (paired; at N = 3074 the default is 15-25 %
    smaller, far beyond the few-% sampling error of N = 40 x 80 scans)."""
    res = {}
    for preset in ("paper", "manoeuvre"):
        cfg = evaluation_config("9S15", preset=preset)
        res[preset] = run_monte_carlo(cfg, 40, seed=7)
    for angle in ("psi_los", "theta_los", "gamma_los", "psi", "theta", "gamma"):
        rms = {p: math.sqrt(float(np.mean(np.square(res[p]["rms"][angle][20:100])))) for p in res}
        assert rms["manoeuvre"] <= rms["paper"], (angle, rms)


@pytest.mark.slow
def test_the_whole_family_default_against_paper() -> None:
    """Every scenario file of the family (24 flights) x 20 runs per preset (about 10 min on a quiet machine)."""
    check_family(list(FILES), runs=20, turn_ratio_max=0.8)
