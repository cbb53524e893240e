"""lbl_nav (digest 000): the two mirror hypotheses, their probabilities, and the fix once one remains.

Per instance (``lbl_nav/<vehicle>``, ``LblFix`` per epoch and ``LblEvent`` s): plan view (truth, the beacons of
any ``BeaconTable``, each hypothesis's track while two are alive, valid fixes with 3σ ellipses), the error of the
valid fixes (east, north) with ±3σ, 2-D NEES, and the story: each hypothesis's posterior probability and
log₁₀ of the ratio against the decision threshold, with the launch and the resolution marked. The hypothesis
that is true is the one nearest the truth at launch; a decision for the other is a wrong decision. Headline:
launch time, resolution time after launch and how (resolved, merged, unique), whether the decision was
right, the horizontal RMS error after resolution and NEES.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from schemas import BeaconTable
from schemas.lbl_nav import LblEvent, LblFix
from shared.foxglove.frames import estimates_of

from .common import RunData, Section, error_series, new_figure, r, render, standard_figures

KIND = "lbl_nav"


def build(data: RunData, metrics: dict[str, dict[str, Any]]) -> list[Section]:
    return [_section(data, src, metrics.get(src.split("/", 1)[1])) for src in data.sources(KIND)]


def beacons(data: RunData) -> dict[str, Any]:
    """Beacon id -> [east, north] of the last BeaconTable in the recording (events or outputs)."""
    out: dict[str, Any] = {}
    for ev in [*data.events, *(e for o in data.outputs.values() for e in o)]:
        if isinstance(ev.msg, BeaconTable):
            out = {b.beacon_id: np.array([[b.x_east_m, b.y_north_m]]) for b in ev.msg.beacons}
    return out


def _section(data: RunData, source: str, entry: dict[str, Any] | None) -> Section:
    instance = source.split("/", 1)[1]
    outs = data.outputs[source]
    fixes = [(ev.key, ev.msg) for ev in outs if isinstance(ev.msg, LblFix)]
    events = [ev.msg for ev in outs if isinstance(ev.msg, LblEvent)]
    platform = fixes[0][1].platform if fixes else instance
    sec = Section(KIND, instance, f"LBL navigation with sparse beacons — {platform}")
    truth = data.truth.get(platform)
    valid = [e for key, f in fixes for e in estimates_of(key, f, data.ctx) if e.kind == "fix"]
    series = error_series(platform, valid, truth, horizontal_only=True)
    plan: dict[str, tuple[Any, Any]] = {}
    hyp_tracks: dict[int, list[Any]] = {}
    for key, f in fixes:
        if not f.valid:
            for e in estimates_of(key, f, data.ctx):
                if e.kind == "hypothesis":
                    hyp_tracks.setdefault(int(e.extra["hypothesis_id"]), []).append(e.position[:2])
    for hid, pts in sorted(hyp_tracks.items()):
        plan[f"hypothesis {hid}"] = (np.array(pts), None)
    if valid:
        plan[f"{platform} fix"] = (np.array([e.position[:2] for e in valid]), np.array([e.cov for e in valid]))
    figs, head = standard_figures(
        [series] if series is not None else [],
        plan_truths={platform: truth.pos[:, :2]} if truth is not None else {},
        plan_estimates=plan,
        points=beacons(data),
    )
    sec.figures += figs
    story, facts = _story(fixes, truth)
    sec.figures.append(story)
    resolved_after = facts.get("resolution_after_launch_s")
    resolved = (
        series.t_s >= facts["resolution_s"] if series is not None and facts.get("resolution_s") is not None else None
    )
    after = series.horizontal_error()[resolved] if series is not None and resolved is not None else np.zeros(0)
    # the paper's Fig. 5 б, в: RMS per axis (σx east, σy north) of the resolved solutions
    per_axis = (
        [r(float(np.sqrt(np.mean(series.err[resolved, c] ** 2)))) for c in (0, 1)]
        if series is not None and resolved is not None and resolved.any()
        else None
    )
    sec.headline = {
        "epochs": len(fixes),
        "launch_s": r(facts.get("launch_s")),
        "resolution_after_launch_s": r(resolved_after),
        "decision": facts.get("decision"),
        "decision_correct": facts.get("correct"),
        "decision_note": facts.get("decision_note"),
        "horizontal_rms_after_resolution_m": r(float(np.sqrt(np.mean(after**2)))) if after.size else None,
        "rms_after_resolution_per_axis_m": per_axis,
        **{k: v for k, v in head.items() if k.startswith("nees")},
        "events": {k: sum(1 for e in events if e.kind == k) for k in sorted({e.kind for e in events})},
    }
    if truth is None:
        sec.notes.append(f"no Truth of {platform} in the recording: errors, NEES and the true hypothesis unknown")
    return sec


def _story(fixes: list[tuple[str, LblFix]], truth: Any) -> tuple[Any, dict[str, Any]]:
    facts: dict[str, Any] = {}
    fig, axs = new_figure(rows=2, height=2.4)
    t = np.array([f.header.stamp_ns / 1e9 for _, f in fixes])
    probs: dict[int, list[float]] = {}
    for i, (_, f) in enumerate(fixes):
        for h in f.hypotheses:
            probs.setdefault(h.hypothesis_id, [math.nan] * len(fixes))[i] = h.probability
    ax = axs[0][0]
    for hid, p in sorted(probs.items()):
        ax.plot(t, p, lw=1.0, label=f"hypothesis {hid}")
    ax.set_ylim(-0.05, 1.05)
    ax.set_ylabel("posterior probability")
    ax.set_title("hypotheses and their probabilities")
    ax2 = axs[1][0]
    ratio = np.array([math.nan if f.log10_ratio is None else f.log10_ratio for _, f in fixes])
    ax2.plot(t, ratio, lw=1.0, color="k", label="log₁₀ δp (1/2)")
    if fixes:
        thr = fixes[-1][1].log10_threshold
        ax2.axhline(thr, color="r", lw=0.7, ls="--", label=f"±log₁₀ threshold ({thr:g})")
        ax2.axhline(-thr, color="r", lw=0.7, ls="--")
    ax2.set_ylabel("log₁₀ ratio")
    ax2.set_xlabel("t, s")
    launch = next((f.launch_stamp_ns for _, f in fixes if f.launch_stamp_ns is not None), None)
    decided = next((f for _, f in fixes if f.resolved_stamp_ns is not None or f.hypothesis_source == "unique"), None)
    for ax in (axs[0][0], ax2):
        if launch is not None:
            ax.axvline(launch / 1e9, color="tab:green", lw=0.8, label="launch")
        if decided is not None and decided.resolved_stamp_ns is not None:
            ax.axvline(decided.resolved_stamp_ns / 1e9, color="tab:purple", lw=0.8, label="resolution")
        if ax.get_legend_handles_labels()[0]:  # nothing labelled (no hypothesis, no launch): no empty legend
            ax.legend(loc="upper right", ncol=3)
    if launch is not None:
        facts["launch_s"] = launch / 1e9
    if decided is not None:
        facts["decision"] = f"{decided.hypothesis_source} (hypothesis {decided.accepted_hypothesis})"
        if decided.resolved_stamp_ns is not None and launch is not None:
            facts["resolution_s"] = decided.resolved_stamp_ns / 1e9
            facts["resolution_after_launch_s"] = (decided.resolved_stamp_ns - launch) / 1e9
            axs[0][0].annotate(
                f"resolved {facts['resolution_after_launch_s']:.0f} s after launch",
                (decided.resolved_stamp_ns / 1e9, 0.5),
                fontsize=7,
                xytext=(4, 0),
                textcoords="offset points",
            )
    # the true hypothesis: the one nearest the truth at the first epoch with two hypotheses
    first_two = next((f for _, f in fixes if len(f.hypotheses) == 2), None)
    if decided is not None and decided.hypothesis_source == "resolved":
        if first_two is None:
            facts["decision_note"] = "resolved at once: no fix carried two hypotheses, so there was no pair to judge"
        elif truth is None:
            facts["decision_note"] = "no truth in the recording to tell which hypothesis was the true one"
        else:
            p = truth.at(np.array([first_two.header.stamp_ns / 1e9]))[0]
            if np.all(np.isfinite(p)):
                d = {h.hypothesis_id: math.dist(h.estimate.mean[:2], p[:2]) for h in first_two.hypotheses}
                facts["correct"] = decided.accepted_hypothesis == min(d, key=lambda u: d[u])
            else:
                facts["decision_note"] = "no truth at the epoch of the two hypotheses to tell which was the true one"
    return render(fig, "Hypotheses, probabilities and resolution", "launch: first epoch with two ranges"), facts
