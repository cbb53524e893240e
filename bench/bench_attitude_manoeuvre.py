"""Attitude estimator (digest 004, issue 15) on manoeuvring flights: the default preset against preset paper.

Every scenario file of the manoeuvring family (``scenarios/attitude_turns_light.yaml``,
``attitude_turns_transport.yaml``, ``attitude_climbs.yaml``, ``attitude_agile.yaml``: 24 flights) and the
paper's straight flight (``attitude_9s15.yaml``) is run through ``fixstream mc``'s code path
(:func:`tools.montecarlo.run_montecarlo`: the player's events, one core per run, the plugin's metrics) with
each preset, and the flight-phase statistics (:func:`services.attitude.metrics.phase_table`) are printed per
preset and phase, pooled over the family and per file: RMS error of heading, pitch, roll (earth frame) and of
the three LOS angles; the state NEES (mean ANEES, the share of scans whose ANEES lies in its chi2(9N) 95 % band,
the share of single NEES values inside the chi2(9) 95 % interval); the VALID consistency (share of estimates
VALID, mean (error / sigma)^2 of the heading among them, share within 2 sigma); resets and gated plots. A second
table pairs the presets on their common support: the RMS of heading, pitch and roll over the samples where BOTH
presets report the angle (the paper preset's resets leave its hardest scans, those right after a manoeuvre,
undefined, which flatters its own RMS), per phase, pooled and per file.

    ATTITUDE_BENCH_RUNS=100 python -m bench attitude_manoeuvre     # the runs per file (default 100)
    ATTITUDE_BENCH_PRESETS=paper,manoeuvre,manoeuvre_ca ...        # presets compared (the first is the base)
    ATTITUDE_BENCH_FILES=attitude_turns_light,attitude_9s15 ...    # only these files (default: the family, 9s15)

Presets ``onset_vjerk_0.3`` / ``onset_vjerk_0.1``: the default bank with the onset model's ``vertical_jerk_factor``;
``turn_sojourn_60`` / ``_120``: the turn model's sojourn; ``turn_dpsi<d>_max<s>``: its exit by heading change;
``bank4_v<sigma>`` (and ``..._turn60``, ``..._dpsi150_max120``, ...): four models, a horizontal onset and a mostly
vertical CA model (``VARIANTS``).

Seeds: ``fixstream mc``'s run seeds from seed 1 (the same plots for both presets: common random numbers).
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from services.attitude.config import CA_MODELS, MANOEUVRE_MODELS, MotionModel
from services.attitude.flights import FILES
from services.attitude.metrics import MIN_LOAD_ROLL, STEADY_AFTER_S, phase_table
from services.player.scenario import load_scenario
from tools.montecarlo import run_montecarlo

from .report import emit, table

SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"
PRESETS = ("paper", "manoeuvre")
#: what a preset label of ATTITUDE_BENCH_PRESETS sets in the configuration: the two presets, and the default
#: preset with the model bank it had before the coordinated-turn model (issue 15, first round)
VARIANTS: dict[str, dict[str, Any]] = {
    "paper": {"preset": "paper"},
    "manoeuvre": {"preset": "manoeuvre"},
    "manoeuvre_ca": {"preset": "manoeuvre", "imm_models": [m.model_dump(mode="json") for m in CA_MODELS]},
}


def bank(changes: dict[str, dict[str, Any]], extra: tuple[dict[str, Any], ...] = ()) -> list[dict[str, Any]]:
    """The default bank (``MANOEUVRE_MODELS``) with the fields in ``changes[name]`` replaced in model ``name``,
    then the models ``extra`` appended, as the JSON a configuration takes (every model validated)."""
    models = [{**m.model_dump(), **changes.get(m.name, {})} for m in MANOEUVRE_MODELS] + list(extra)
    return [MotionModel.model_validate(m).model_dump(mode="json") for m in models]


def onset_vertical(factor: float) -> list[dict[str, Any]]:
    """The default bank with the onset model's vertical jerk std scaled by ``factor`` (``vertical_jerk_factor``)."""
    return bank({"onset": {"vertical_jerk_factor": factor}})


def vertical_model(sigma_jerk_mps3: float, factor: float, sojourn_s: float = 20.0) -> dict[str, Any]:
    """A ``vertical`` CA model: horizontal jerk std ``sigma_jerk_mps3``, vertical ``factor`` times it (pull-ups,
    push-overs, climb entries and exits), exits to any model."""
    return {
        "name": "vertical",
        "kind": "ca",
        "sigma_jerk_mps3": sigma_jerk_mps3,
        "vertical_jerk_factor": factor,
        "sojourn_s": sojourn_s,
    }


#: the default bank with a quieter vertical jerk in the onset model (docs/attitude.md, "The onset model's
#: vertical jerk"): labels ``onset_vjerk_<factor>``
VARIANTS.update({f"onset_vjerk_{k}": {"preset": "manoeuvre", "imm_models": onset_vertical(k)} for k in (0.3, 0.1)})
#: the turn model's exit (docs/attitude.md, "A bank for turns and vertical manoeuvres"): a longer sojourn (exits
#: unchanged), or an exit by heading change (``exit_heading_change_deg``, the sojourn its longest mean sojourn);
#: ``_xs``: the turn exits to straight flight only
_XS60 = {"exit_heading_change_deg": 90.0, "sojourn_s": 60.0, "exits_to": ["straight"]}
TURN_EXITS: dict[str, dict[str, Any]] = {
    "turn60": {"sojourn_s": 60.0},
    "turn120": {"sojourn_s": 120.0},
    **{
        f"dpsi{d}_max{s}": {"exit_heading_change_deg": float(d), "sojourn_s": float(s)}
        for d in (90, 150)
        for s in (60, 120)
    },
    "dpsi90_max30": {"exit_heading_change_deg": 90.0, "sojourn_s": 30.0},
    "xs": {"exits_to": ["straight"]},
    "turn60_xs": {"sojourn_s": 60.0, "exits_to": ["straight"]},
    "dpsi90_max30_xs": {"exit_heading_change_deg": 90.0, "sojourn_s": 30.0, "exits_to": ["straight"]},
    "dpsi90_max60_xs": _XS60,
    "dpsi150_max120_xs": {"exit_heading_change_deg": 150.0, "sojourn_s": 120.0, "exits_to": ["straight"]},
    # the same with more turn-model noise (deviation sigma_a 0.5 m/s^2; turn-rate noise 0.2 deg/s per root s)
    "dpsi90_max60_xs_a0.5": {**_XS60, "sigma_accel_mps2": 0.5},
    "dpsi90_max60_xs_w0.2": {**_XS60, "sigma_turn_rate_dps": 0.2},
}
#: a ``vertical`` CA model: (horizontal jerk sigma, vertical factor, sojourn), labelled by its vertical sigma
#: (m/s^3) and, where they are not 0.1 and 20 s, its horizontal sigma (``h<sigma>``) and sojourn (``s<s>``)
VERTICAL_MODELS = {
    "1.0": (0.1, 10.0, 20.0),
    "0.5": (0.05, 10.0, 20.0),
    "1.5": (0.15, 10.0, 20.0),
    "2.0": (0.2, 10.0, 20.0),
    "1.0h0.3": (0.3, 10.0 / 3.0, 20.0),
    "1.0h0.5": (0.5, 2.0, 20.0),
    "1.5h0.3": (0.3, 5.0, 20.0),
    "2.0h0.5": (0.5, 4.0, 20.0),
    "1.0s10": (0.1, 10.0, 10.0),
    "2.0s10": (0.2, 10.0, 10.0),
}
#: the onset model's vertical_jerk_factor in the four-model bank: 0.1 (no label) or 0.3 (``bank4o0.3``)
ONSET_FACTORS = {"": 0.1, "o0.3": 0.3}
#: labels ``turn_sojourn_<s>`` and ``turn_dpsi<d>_max<s>``: the default bank with the turn's exit changed
VARIANTS.update(
    {
        (f"turn_sojourn_{k.removeprefix('turn')}" if k.startswith("turn") else f"turn_{k}"): {
            "preset": "manoeuvre",
            "imm_models": bank({"turn": turn}),
        }
        for k, turn in TURN_EXITS.items()
    }
)
#: the candidate turn exit with a shorter straight sojourn (more manoeuvre probability on straight legs, the
#: turn ANEES's lever in "Why these values"): labels ``turn_dpsi90_max60_xs_straight<s>``
VARIANTS.update(
    {
        f"turn_dpsi90_max60_xs_straight{s}": {
            "preset": "manoeuvre",
            "imm_models": bank({"turn": _XS60, "straight": {"sojourn_s": float(s)}}),
        }
        for s in (100, 150)
    }
)
#: four models, labels ``bank4[o0.3]_v<vertical sigma>[_<turn exit>]``: the onset horizontal (k = 0.1, or 0.3), a
#: ``vertical`` model appended (exits to any model; mu starts at the default rule's (0.9, 1/30, 1/30, 1/30)), and
#: optionally the turn's exit of ``TURN_EXITS``
for _o, _factor in ONSET_FACTORS.items():
    for _v, (_s, _k, _sojourn) in VERTICAL_MODELS.items():
        for _exit in (None, *TURN_EXITS):
            _changes: dict[str, dict[str, Any]] = {"onset": {"vertical_jerk_factor": _factor}}
            if _exit is not None:
                _changes["turn"] = TURN_EXITS[_exit]
            VARIANTS[f"bank4{_o}_v{_v}" + ("" if _exit is None else f"_{_exit}")] = {
                "preset": "manoeuvre",
                "imm_models": bank(_changes, (vertical_model(_s, _k, _sojourn),)),
            }
PHASES = ("turn", "manoeuvre", "straight", "steady")
SEED = 1


def run_file(name: str, preset: str, runs: int, workers: int) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The aggregate of the attitude estimator of scenario ``name`` with ``preset`` (reference rules off), and
    per run and target the errors of heading, pitch and roll with the phase of every scan (for the pairing)."""
    sc = load_scenario(SCENARIOS / f"{name}.yaml")
    est = sc.estimators[0]
    params = {
        **dict(est.params),
        "reference": False,
        "config": {**dict(est.params).get("config", {}), **VARIANTS[preset]},
    }
    sc = sc.model_copy(update={"estimators": [est.model_copy(update={"params": params})]})
    result = run_montecarlo(sc, runs, seed=SEED, workers=workers, progress=False)
    agg: dict[str, Any] = result["aggregate"]["estimators"][est.instance]
    records = []
    for run in result["per_run"]:
        for tid, rec in run["estimators"][est.instance]["targets"].items():
            records.append(
                {
                    "key": (run["run"], tid),
                    "phase": rec["phase"],
                    "since": rec["since_manoeuvre_s"],
                    "load": rec["load_factor_true"],
                    "err": {a: rec["err"][a] for a in PAIRED_ANGLES},
                }
            )
    return agg, records


PAIRED_ANGLES = ("psi", "theta", "gamma")
FIRST_SCAN = 20


def _f(v: Any) -> float:
    return math.nan if v is None else float(v)


def paired(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per phase and angle: RMS (deg) of presets a and b over the samples (scan >= FIRST_SCAN, roll where the true
    load factor >= MIN_LOAD_ROLL) where both report the angle, the number of such samples, and the share of the
    phase's samples that each preset reports."""
    by_key = {r["key"]: r for r in b}
    acc: dict[str, dict[str, np.ndarray]] = {}  # [samples, reported by a, by b, by both, sum sq a, sum sq b]
    for ra in a:
        rb = by_key[ra["key"]]
        n = min(len(ra["phase"]), len(rb["phase"]))
        for k in range(FIRST_SCAN - 1, n):
            ph = ra["phase"][k]
            if ph is None:
                continue
            phases = [ph] + (["steady"] if ph == "straight" and _f(ra["since"][k]) > STEADY_AFTER_S else [])
            for angle in PAIRED_ANGLES:
                if angle == "gamma" and not _f(ra["load"][k]) >= MIN_LOAD_ROLL:
                    continue
                ea, eb = _f(ra["err"][angle][k]), _f(rb["err"][angle][k])
                fa, fb = math.isfinite(ea), math.isfinite(eb)
                both = fa and fb
                row = np.array([1.0, fa, fb, both, ea * ea if both else 0.0, eb * eb if both else 0.0])
                for p in phases:
                    cell = acc.setdefault(p, {}).get(angle)
                    acc[p][angle] = row if cell is None else cell + row
    out: dict[str, dict[str, Any]] = {}
    for p, angles in acc.items():
        out[p] = {}
        for angle, (n, da, db, nb, sa, sb) in angles.items():
            out[p][angle] = {
                "samples": int(n),
                "defined_a": da / n,
                "defined_b": db / n,
                "both": int(nb),
                "rms_a": math.sqrt(sa / nb) if nb else None,
                "rms_b": math.sqrt(sb / nb) if nb else None,
            }
    return out


def rows_of(label: str, preset: str, phases: dict[str, Any], core: dict[str, int]) -> list[list[Any]]:
    rows = []
    for ph in PHASES:
        r = phases.get(ph)
        if r is None:
            continue
        rms, nees, valid = r["rms_deg"], r["nees"], r["valid"]["psi"]
        rows.append(
            [
                label,
                preset,
                ph,
                r["samples"],
                rms["psi"],
                rms["theta"],
                rms["gamma"],
                rms["psi_los"],
                rms["theta_los"],
                rms["gamma_los"],
                r["defined"]["psi"],
                nees["anees_mean"],
                nees["anees_in_band"],
                nees["sample_in_95"],
                valid["share"],
                valid["mean_z2"],
                valid["within_2sigma"],
                core.get("reset_nis", 0),
                core.get("innovation_gate", 0),
            ]
        )
    return rows


def main() -> None:
    runs = int(os.environ.get("ATTITUDE_BENCH_RUNS", "100"))
    workers = int(os.environ.get("ATTITUDE_BENCH_WORKERS", "1"))
    presets = tuple(os.environ.get("ATTITUDE_BENCH_PRESETS", ",".join(PRESETS)).split(","))
    chosen = os.environ.get("ATTITUDE_BENCH_FILES")
    files = chosen.split(",") if chosen else [*FILES, "attitude_9s15"]
    family_files = [n for n in FILES if n in files]
    results: dict[str, dict[str, Any]] = {}
    records: dict[str, list[dict[str, Any]]] = {}
    t0 = time.perf_counter()
    for preset in presets:
        for name in files:
            results[f"{name}/{preset}"], records[f"{name}/{preset}"] = run_file(name, preset, runs, workers)
    rows: list[list[Any]] = []
    figures: dict[str, Any] = {"runs_per_file": runs, "seed": SEED, "seconds": time.perf_counter() - t0}
    for preset in presets:
        family = [results[f"{name}/{preset}"] for name in family_files]
        pooled = phase_table([s for agg in family for s in agg["phase_samples"]])
        core: dict[str, int] = {}
        for agg in family:
            for k, n in agg["core"].items():
                core[k] = core.get(k, 0) + int(n)
        rows += rows_of("family", preset, pooled, core)
        figures[f"family/{preset}"] = {"phases": pooled, "core": core}
    for name in files:
        for preset in presets:
            agg = results[f"{name}/{preset}"]
            rows += rows_of(name.removeprefix("attitude_"), preset, agg["phases"], agg["core"])
            figures[f"{name}/{preset}"] = {"phases": agg["phases"], "core": agg["core"]}
    # the presets paired against the first one (paper) on their common support
    prows: list[list[Any]] = []
    base = presets[0]
    for preset in presets[1:]:
        for label, names in [("family", family_files), *[(n.removeprefix("attitude_"), [n]) for n in files]]:
            pa = paired(
                [r for n in names for r in records[f"{n}/{base}"]],
                [r for n in names for r in records[f"{n}/{preset}"]],
            )
            figures[f"paired/{label}/{base}/{preset}"] = pa
            for ph in PHASES:
                if ph not in pa:
                    continue
                cells: list[Any] = [label, f"{base} / {preset}", ph]
                for angle in PAIRED_ANGLES:
                    c = pa[ph][angle]
                    cells += [c["rms_a"], c["rms_b"], f"{c['defined_a']:.3f} / {c['defined_b']:.3f}"]
                prows.append(cells)
    headers = [
        "scenario",
        "preset",
        "phase",
        "samples",
        "psi",
        "theta",
        "gamma",
        "psi_los",
        "theta_los",
        "gamma_los",
        "psi defined",
        "ANEES",
        "ANEES in band",
        "NEES in 95%",
        "VALID share",
        "VALID z2 psi",
        "VALID |z|<=2",
        "NIS resets",
        "gated",
    ]
    emit("attitude_manoeuvre", headers, rows, figures)
    pheaders = ["scenario", "presets", "phase"]
    for angle in PAIRED_ANGLES:
        pheaders += [f"{angle} a", f"{angle} b", f"{angle} reported a / b"]
    print("\n## attitude_manoeuvre: paired on the common support (RMS over the samples both presets report)\n")
    print(table(pheaders, prows))


if __name__ == "__main__":
    main()
