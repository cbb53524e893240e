"""Attitude estimator (issue 15): a near-optimal reference (a Rao-Blackwellised particle filter) against the IMM.

Is the default preset's IMM leaving accuracy on the table in turns, or are the issue's targets (heading RMS in
turns <= 2 x straight; the 9-state NEES inside its 95 % band in turns and on straight legs) beyond what a causal
estimator can get from these plots? ``bench/attitude_reference_pf.py`` is a second, independent estimator whose
prior is the family generator's statistics (jump-Markov straight / coordinated turn / other manoeuvre, the
generator's banks, heading changes and wander). Every stream sees the same plots (``fixstream mc``'s run seeds
from 1) and is scored like ``bench_attitude_smoother`` (``mc.run_metrics`` and ``metrics.phase_table``: phases
from the truth's ``extra``, from scan 20, the 9-state ANEES against its chi2(9N) 95 % band):

* ``paper``: preset paper (real time);
* ``IMM``: the default preset's IMM (real time), and ``IMM L=3``: its lag-3 smoothed estimate (one core with
  ``smoother_lag_scans: 3``, whose real-time stream is the L = 0 one);
* ``PF``: the reference filter (real time); the angles from its posterior mean 9-state by the core's own angle
  block (the service rules of the default preset, as for the IMM), the NEES against its posterior covariance;
* ``PF | S``: a diagnostic, the same particles' straight-regime hypotheses alone (the posterior conditioned on
  "no manoeuvre now"): on straight legs, how much of the PF's NEES deficit is the spread of its manoeuvre
  hypotheses.

A second table splits the heading RMS of the turns by the scans since the turn began (and the first scans after it
ended): where in a turn each stream makes its error.

    ATTITUDE_REFERENCE_RUNS=6 ATTITUDE_REFERENCE_PARTICLES=3000 python -m bench attitude_reference
    ATTITUDE_REFERENCE_WORKERS=2 ...                  # processes (default 1)
    ATTITUDE_REFERENCE_FILES=attitude_turns_light ... # only these files (default: the four family files)
    ATTITUDE_REFERENCE_PRIOR='{"turn_exit_sojourn_s": 20}' ...   # a prior field changed (an ablation)
"""

from __future__ import annotations

import json
import math
import os
import time
import zlib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from typing import Any

import numpy as np

from schemas import RadarPlot, RadarSite
from services.attitude import core as attitude_core
from services.attitude.flights import FILES
from services.attitude.geometry import convert_plot
from services.attitude.mc import Params, aggregate, core_outputs, run_metrics
from services.attitude.metrics import phase_table
from services.player.scenario import load_scenario
from services.player.simulators import Event
from services.player.timeline import build, player_source, stamp
from shared import keys
from tools.montecarlo import EVENT_INSTANCE

from .attitude_reference_pf import ManoeuvrePrior, ReferencePF, S
from .bench_attitude_manoeuvre import SCENARIOS, SEED
from .report import emit, table

STREAMS = ("paper", "IMM", "IMM L=3", "PF", "PF | S")
DELAY = {"paper": "0", "IMM": "0", "IMM L=3": "15 s", "PF": "0", "PF | S": "0 (diagnostic)"}
LAG = 3
#: the first plot with an output (the IMM's FSF start needs three)
FIRST_OUTPUT = 3
_D2R = math.pi / 180.0


def reference_prior() -> ManoeuvrePrior:
    """The reference's prior: the generator's law, with the fields of ATTITUDE_REFERENCE_PRIOR (a JSON object,
    e.g. an ablation ``{"turn_exit_sojourn_s": 20}``) replaced."""
    return replace(ManoeuvrePrior(), **json.loads(os.environ.get("ATTITUDE_REFERENCE_PRIOR", "{}")))


def reference_outputs(
    events: list[Event], params: dict[str, Any], scenario: Any, n_particles: int, seed: list[int]
) -> tuple[list[Event], list[Event], float, int]:
    """(PF estimates, PF | S estimates, PF seconds, plots) of one run: one ReferencePF per target over its plots,
    each posterior turned into an AttitudeEstimate by the core's own output block (angles, sigmas, heading rule)."""
    p = Params.model_validate(params, strict=True)
    site = next(e.msg for e in events if isinstance(e.msg, RadarSite))
    cfg = p.core_config(site.site_id).model_copy(update={"raw_output": False})
    core = attitude_core.AttitudeCore(cfg)
    prefix = f"{keys.ROOT}/sensor/{site.site_id}/radar/"
    out_prefix = f"{keys.ROOT}/fix/attitude/{site.site_id}/"
    plots: dict[str, list[RadarPlot]] = {}
    for ev in events:
        if isinstance(ev.msg, RadarPlot) and ev.key.startswith(prefix):
            plots.setdefault(ev.msg.target_id, []).append(ev.msg)
    prior = reference_prior()
    out: list[Event] = []
    out_s: list[Event] = []
    seconds = 0.0
    n_plots = 0
    for tid, pl in plots.items():
        rng = np.random.default_rng([*seed, zlib.crc32(tid.encode())])
        pf = ReferencePF(prior, n_particles, rng)
        track = attitude_core._Track(site.site_id, tid, cfg.fsf_n)
        for k, m in enumerate(pl):
            z, rz = convert_plot(
                m.range_m,
                (m.az_deg % 360.0) * _D2R,
                m.el_deg * _D2R,
                m.sigma_r_m or site.sigma_r_m,
                (m.sigma_az_deg or site.sigma_az_deg) * _D2R,
                (m.sigma_el_deg or site.sigma_el_deg) * _D2R,
            )
            t_s = m.header.stamp_ns / 1e9
            t0 = time.perf_counter()
            if k == 0:
                pf.start(t_s, z, rz)
            else:
                pf.step(t_s, z, rz)
            seconds += time.perf_counter() - t0
            n_plots += 1
            track.n_updates = k + 1
            if k + 1 < FIRST_OUTPUT:
                continue
            stamp_ns = m.header.stamp_ns
            x, cov = pf.moments()
            est = core._estimate(track, stamp_ns, x, cov, [], None, None, None)
            out.append(Event(stamp_ns, out_prefix + tid, est))
            straight = pf.regime == S
            if straight.any() and pf.weights()[straight].sum() > 0.0:
                xs, cs = pf.moments(straight)
                est_s = core._estimate(track, stamp_ns, xs, cs, [], None, None, None)
                out_s.append(Event(stamp_ns, out_prefix + tid, est_s))
    return out, out_s, seconds, n_plots


def run_one(name: str, run: int, n_particles: int) -> dict[str, Any]:
    """One run of one file: per stream the run_metrics record (with the counters aggregate wants), the PF's time."""
    sc = load_scenario(SCENARIOS / f"{name}.yaml")
    events = list(stamp(build(sc, SEED, run).raw_events(), player_source(EVENT_INSTANCE)))
    params: dict[str, Any] = {"reference": False, "config": {}}
    metrics: dict[str, Any] = {}
    paper = {"reference": False, "config": {"preset": "paper"}}
    outputs, rejected, counters = core_outputs(events, paper, sc)
    metrics["paper"] = {**run_metrics(outputs, events, paper, sc), "rejected": rejected, "core": counters}
    lagged = {"reference": False, "config": {"smoother_lag_scans": LAG}}
    outputs, rejected, counters = core_outputs(events, lagged, sc)
    extra = {"rejected": rejected, "core": counters}
    metrics["IMM"] = {**run_metrics(outputs, events, lagged, sc), **extra}
    metrics["IMM L=3"] = {**run_metrics(outputs, events, lagged, sc, smoothed=True), **extra}
    pf_out, pf_s_out, seconds, n_plots = reference_outputs(
        events, params, sc, n_particles, [SEED, run, zlib.crc32(name.encode())]
    )
    none = {"rejected": 0, "core": {}}
    metrics["PF"] = {**run_metrics(pf_out, events, params, sc), **none}
    metrics["PF | S"] = {**run_metrics(pf_s_out, events, params, sc), **none}
    return {"metrics": metrics, "pf_seconds": seconds, "pf_plots": n_plots}


def _fmt(v: float | None, digits: int = 2) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def _three(phases: dict[str, Any], phase: str) -> str:
    r = phases.get(phase)
    if not r:
        return "-"
    rms = r["rms_deg"]
    return " / ".join(_fmt(rms[a]) for a in ("psi", "theta", "gamma"))


def _ratio(phases: dict[str, Any]) -> float | None:
    turn, straight = phases.get("turn"), phases.get("straight")
    if not turn or not straight or not turn["rms_deg"]["psi"] or not straight["rms_deg"]["psi"]:
        return None
    return float(turn["rms_deg"]["psi"] / straight["rms_deg"]["psi"])


def _nees(phases: dict[str, Any], phase: str, key: str) -> str:
    r = phases.get(phase)
    return "-" if not r or r["nees"][key] is None else _fmt(r["nees"][key], 1 if key == "anees_mean" else 2)


def summary_row(label: str, stream: str, phases: dict[str, Any]) -> list[Any]:
    band = next((phases[ph]["nees"]["band_at_min_runs"] for ph in ("straight", "turn") if ph in phases), None)
    return [
        label,
        stream,
        DELAY[stream],
        _fmt(_ratio(phases)),
        _three(phases, "turn"),
        _three(phases, "manoeuvre"),
        _three(phases, "straight"),
        _three(phases, "steady"),
        f"{_nees(phases, 'turn', 'anees_mean')} / {_nees(phases, 'straight', 'anees_mean')} / "
        f"{_nees(phases, 'steady', 'anees_mean')}",
        f"[{band[0]:.1f}, {band[1]:.1f}]" if band else "-",
        f"{_nees(phases, 'turn', 'sample_in_95')} / {_nees(phases, 'straight', 'sample_in_95')}",
        f"{_nees(phases, 'turn', 'anees_in_band')} / {_nees(phases, 'straight', 'anees_in_band')}",
    ]


#: bins of the heading profile through a turn: scans since the turn's first sample (1 = the first plot after the
#: roll-in began), and the first scans after it ended ("after 1-2": the roll-out and the scan after it)
PROFILE_BINS: tuple[tuple[str, int, int], ...] = (
    ("turn 1-2", 1, 2),
    ("turn 3-4", 3, 4),
    ("turn 5-8", 5, 8),
    ("turn 9+", 9, 10**6),
    ("after 1-2", -2, -1),
    ("after 3-6", -6, -3),
)


def turn_profile(records: list[dict[str, Any]], first_scan: int = 20) -> dict[str, tuple[float | None, int]]:
    """Heading RMS (deg) and sample count per PROFILE_BINS over per-run records of one stream (run_metrics'
    ``targets`` values), from ``first_scan`` on: where in a turn the error is made."""
    sq = {name: 0.0 for name, _, _ in PROFILE_BINS}
    cnt = dict.fromkeys(sq, 0)
    for rec in records:
        phase, err = rec["phase"], rec["err"]["psi"]
        run_len, since_end = 0, 10**6
        for k, ph in enumerate(phase):
            if ph == "turn":
                run_len += 1
                pos = run_len
            else:
                since_end = 1 if run_len else since_end + 1
                run_len = 0
                pos = -since_end
            e = err[k]
            if k < first_scan - 1 or e is None or not math.isfinite(e):
                continue
            for name, lo, hi in PROFILE_BINS:
                if lo <= pos <= hi:
                    sq[name] += e * e
                    cnt[name] += 1
    return {n: (math.sqrt(sq[n] / cnt[n]) if cnt[n] else None, cnt[n]) for n in sq}


def main() -> None:
    runs = int(os.environ.get("ATTITUDE_REFERENCE_RUNS", "6"))
    n_particles = int(os.environ.get("ATTITUDE_REFERENCE_PARTICLES", "3000"))
    workers = int(os.environ.get("ATTITUDE_REFERENCE_WORKERS", "1"))
    chosen = os.environ.get("ATTITUDE_REFERENCE_FILES")
    files = chosen.split(",") if chosen else list(FILES)
    tasks = [(name, run) for name in files for run in range(runs)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=workers) as pool:
        results = list(pool.map(run_one, *zip(*tasks, strict=True), [n_particles] * len(tasks)))
    per_file: dict[str, dict[str, list[dict[str, Any]]]] = {n: {s: [] for s in STREAMS} for n in files}
    pf_seconds = sum(r["pf_seconds"] for r in results)
    pf_plots = sum(r["pf_plots"] for r in results)
    for (name, _), res in zip(tasks, results, strict=True):
        for s in STREAMS:
            per_file[name][s].append(res["metrics"][s])
    figures: dict[str, Any] = {
        "runs_per_file": runs,
        "particles": n_particles,
        "seed": SEED,
        "seconds": time.perf_counter() - t0,
        "pf_ms_per_plot": 1e3 * pf_seconds / max(pf_plots, 1),
        "prior": reference_prior().__dict__,
    }
    rows: list[list[Any]] = []
    groups = [("family", files)] if len(files) > 1 else []
    for label, names in [*groups, *[(n.removeprefix("attitude_"), [n]) for n in files]]:
        for s in STREAMS:
            aggs = [aggregate(per_file[n][s]) for n in names]
            phases = phase_table([p for a in aggs for p in a["phase_samples"]])
            figures[f"{label}/{s}"] = phases
            rows.append(summary_row(label, s, phases))
    headers = [
        "scenario",
        "stream",
        "delay",
        "psi turn / straight",
        "psi / theta / gamma turn",
        "manoeuvre",
        "straight",
        "steady",
        "ANEES turn / straight / steady",
        "band",
        "NEES in chi2_9 95 % turn / straight",
        "scans with ANEES in band turn / straight",
    ]
    profile_rows = []
    for s in STREAMS:
        recs = [rec for n in files for run in per_file[n][s] for rec in run["targets"].values()]
        prof = turn_profile(recs)
        figures[f"turn_profile/{s}"] = prof
        profile_rows.append([s, *(_fmt(prof[name][0]) for name, _, _ in PROFILE_BINS)])
    counts = turn_profile([rec for n in files for run in per_file[n]["PF"] for rec in run["targets"].values()])
    emit("attitude_reference", headers, rows, figures)
    print("\n## heading RMS (deg) through the turns, all files pooled: scans since the turn began / ended\n")
    print(table(["stream", *(f"{n} ({counts[n][1]})" for n, _, _ in PROFILE_BINS)], profile_rows))
    print(f"\n{runs} runs per file, {n_particles} particles, PF {figures['pf_ms_per_plot']:.1f} ms per plot")
    print(table(["", ""], [["wall time (s)", figures["seconds"]]]))


if __name__ == "__main__":
    main()
