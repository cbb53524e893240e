"""terrain_nav (digest 001): corrected positions against truth, and which of C1–C4 held at each evaluation.

Per instance (``terrain_nav/<instance>``, vehicle from its keys ``fixstream/fix/terrain/<vehicle>[/verdict]``):
plan view (truth, INS-indicated track, fixes with 3σ ellipses of the ``estimate`` block), error of the corrected
position (east = transverse z, north = longitudinal x) with ±3σ, 2-D NEES, and the verdicts: the four
condition flags and the state word over time. Headline: fixes, first fix, the error in cells and false fixes
(from the mc plugin's metrics when the scenario is known), verdict states, horizontal RMS and NEES.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from schemas import InsSample
from schemas.terrain_nav import TerrainFix, TerrainVerdict
from shared.foxglove.frames import estimates_of

from .common import RunData, Section, error_series, new_figure, r, render, standard_figures

KIND = "terrain_nav"
STATES = ["ACQUIRING", "NO_FIX_FIT", "NO_FIX_AMBIGUOUS", "NO_FIX_UNSTABLE", "FIX", "OUT_OF_ZONE", "GAP", "RESET"]


def build(data: RunData, metrics: dict[str, dict[str, Any]]) -> list[Section]:
    return [_section(data, src, metrics.get(src.split("/", 1)[1])) for src in data.sources(KIND)]


def _section(data: RunData, source: str, entry: dict[str, Any] | None) -> Section:
    instance = source.split("/", 1)[1]
    outs = data.outputs[source]
    fixes = [(ev.key, ev.msg) for ev in outs if isinstance(ev.msg, TerrainFix)]
    verdicts = [ev.msg for ev in outs if isinstance(ev.msg, TerrainVerdict)]
    keys_ = {ev.key for ev in outs if isinstance(ev.msg, TerrainFix | TerrainVerdict)}
    vehicle = next((k.split("/")[3] for k in sorted(keys_) if k.count("/") >= 3), instance)
    sec = Section(KIND, instance, f"Terrain-aided navigation — {instance} (vehicle {vehicle})")
    ests = [e for key, f in fixes for e in estimates_of(key, f, data.ctx)]
    truth = data.truth.get(vehicle)
    series = error_series(vehicle, ests, truth, horizontal_only=True)
    prefix = f"fixstream/sensor/{vehicle}/"
    ins_raw = [
        (ins_msg.x_m, ins_msg.z_m, ins_msg.h_m)
        for ev in data.events
        if isinstance((ins_msg := ev.msg), InsSample) and ev.key.startswith(prefix)
    ]
    ins = data.ctx.to_enu_array(np.array(ins_raw, dtype=np.float64).reshape(-1, 3), "map")
    truths = {vehicle: truth.pos[:, :2]} if truth is not None else {}
    plan: dict[str, tuple[Any, Any]] = {}
    if len(ins):
        plan["INS indicated"] = (ins[:, :2], None)
    if ests:
        plan[f"{vehicle} fixes"] = (
            np.array([e.position[:2] for e in ests]),
            np.array([e.cov for e in ests]) if all(e.cov is not None for e in ests) else None,
        )
    figs, head = standard_figures(
        [series] if series is not None else [],
        plan_truths=truths,
        plan_estimates=plan,
        axes_names=("east (transverse z)", "north (longitudinal x)"),
    )
    sec.figures += figs
    sec.figures.append(_verdict_figure(verdicts))
    states = Counter(v.state for v in verdicts)
    first = fixes[0][1].header.stamp_ns / 1e9 if fixes else None
    sec.headline = {
        "fixes": len(fixes),
        "verdicts": len(verdicts),
        "first_fix_s": r(first),
        "states": dict(sorted(states.items())),
        **head,
    }
    m: dict[str, Any] | None = entry.get("metrics") if entry else None
    if m:
        sec.headline.update(
            {
                "max_abs_error_cells": r(m.get("max_abs_error_cells")),
                "false_fixes_over_1_cell": m.get("n_false_fixes"),
                "available": m.get("available"),
            }
        )
    if truth is None:
        sec.notes.append(f"no Truth of {vehicle} in the recording: errors and NEES cannot be computed")
    return sec


def _verdict_figure(verdicts: list[TerrainVerdict]) -> Any:
    fig, axs = new_figure(rows=2, height=2.2)
    ax = axs[0][0]
    evals = [v for v in verdicts if v.state not in ("OUT_OF_ZONE", "GAP", "RESET")]
    t = np.array([v.header.stamp_ns / 1e9 for v in evals])
    names = ["C1 enough data", "C2 fit", "C3 unique", "C4 stable"]
    for i, attr in enumerate(("c1_enough_data", "c2_fit", "c3_unique", "c4_stable")):
        ok = np.array([bool(getattr(v, attr)) for v in evals])
        if t.size:
            ax.scatter(t[ok], np.full(ok.sum(), i), c="tab:green", marker="s", s=14)
            ax.scatter(t[~ok], np.full((~ok).sum(), i), c="tab:red", marker="x", s=14)
    ax.set_yticks(range(4), names)
    ax.set_ylim(-0.6, 3.6)
    ax.set_title("reliability conditions per evaluation (green: held, red ×: failed)")
    ax.set_xlabel("t, s")
    ax = axs[1][0]
    ts = np.array([v.header.stamp_ns / 1e9 for v in verdicts])
    ys = np.array([STATES.index(v.state) for v in verdicts])
    if ts.size:
        ax.step(ts, ys, where="post", lw=0.8, color="0.5")
        ax.scatter(ts, ys, c=["tab:green" if v.valid else "tab:orange" for v in verdicts], s=12, zorder=3)
    ax.set_yticks(range(len(STATES)), STATES)
    ax.set_title("verdict state over time (green: fix issued)")
    ax.set_xlabel("t, s")
    return render(
        fig, "Terrain verdicts C1–C4 over time", "which reliability condition blocked a fix, and when", left_in=2.0
    )
