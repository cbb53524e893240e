"""The papers' own figures (from the digests in ``../shared/seeds/``) and this run's verdict against each.

Every estimator kind has the figures its paper reports as numbers, each with what it measures in words, the
number as the paper states it, and a check of one run against it (a list of :class:`PaperFigure` its plugin
names, ``ReportSection.paper``; the repository's estimators' lists are here, one per kind):

* ``pass`` — this run's number is within the paper's figure;
* ``outside`` — it is not (one run of a different scenario can be outside a Monte-Carlo figure for good reasons:
  the page says what the paper's set-up was, and ``fixstream mc`` does the statistics);
* ``not comparable`` — the run cannot say (e.g. the paper's figure is from the 40th contact on and the run has
  fewer), with the reason;
* ``no data`` — nothing to score (no fix, no decision, no truth).

The checks read the section's headline (the report's own numbers) and the mc plugin's metrics; a figure's
``source`` (digest and section) stays in ``metrics.json`` for whoever wants to look it up.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from typing import Any

from shared.plugins import report_sections, resolve

PASS, OUTSIDE, NOT_COMPARABLE, NO_DATA = "pass", "outside", "not comparable", "no data"


@dataclass(frozen=True)
class Verdict:
    """One row of the summary: an estimator (and a platform of it) against one figure of its paper."""

    kind: str
    instance: str
    #: the platform or target the row is about ("" when the estimator has one)
    subject: str
    #: what the paper measured, in words, with its set-up
    what: str
    #: the paper's figure as it states it, with units
    paper: str
    #: this run's number(s), with units
    this_run: str
    verdict: str
    #: why not comparable, or what to keep in mind
    note: str = ""
    #: where in the digests the figure is
    source: str = ""

    def as_json(self) -> dict[str, str]:
        return asdict(self)


@dataclass(frozen=True)
class PaperFigure:
    what: str
    paper: str
    source: str
    #: (headline, plugin metrics or None) -> rows of (subject, this run, verdict, note)
    check: Callable[[dict[str, Any], dict[str, Any] | None], Iterator[tuple[str, str, str, str]]]


def _num(v: Any) -> float | None:
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) else None


def _g(v: float, digits: int = 3) -> str:
    return f"{v:.{digits}g}"


# ----- terrain_nav (digest 001) -------------------------------------------------------------------------------


def _terrain_error(head: dict[str, Any], m: dict[str, Any] | None) -> Iterator[tuple[str, str, str, str]]:
    if not m:
        yield "", "—", NO_DATA, "needs the scenario (the cell size and the truth in map cells): no mc metrics"
        return
    worst = _num(m.get("max_abs_error_cells"))
    n, false = m.get("n_fixes", 0), m.get("n_false_fixes", 0)
    if worst is None or not n:
        yield "", "no fix issued", NO_DATA, ""
        return
    text = f"{_g(worst)} cells (worst of {n} fixes; {false} beyond 1 cell)"
    yield "", text, PASS if worst <= 1.0 else OUTSIDE, ""


# ----- lbl_nav (digest 000) -----------------------------------------------------------------------------------


def _lbl_decision(head: dict[str, Any], m: dict[str, Any] | None) -> Iterator[tuple[str, str, str, str]]:
    correct = head.get("decision_correct")
    decision = head.get("decision")
    if correct is None:
        if decision is None:
            yield "", "no decision between the two hypotheses", NO_DATA, ""
        elif str(decision).startswith("resolved"):
            note = head.get("decision_note") or "no truth to tell which hypothesis was the true one"
            yield "", f"decision: {decision}", NO_DATA, note
        else:
            yield "", f"decision: {decision}", NO_DATA, "no choice between two hypotheses to judge"
        return
    yield "", "the true one" if correct else "the FALSE one", PASS if correct else OUTSIDE, ""


def _lbl_resolution(head: dict[str, Any], m: dict[str, Any] | None) -> Iterator[tuple[str, str, str, str]]:
    t = _num(head.get("resolution_after_launch_s"))
    if t is None:
        yield "", "not resolved", NO_DATA, ""
        return
    note = "one field case (track 35° to the beacon line); the time depends on the geometry and the turns"
    yield "", f"{_g(t)} s after launch", PASS if t <= 16.0 else OUTSIDE, note


def _lbl_rms(head: dict[str, Any], m: dict[str, Any] | None) -> Iterator[tuple[str, str, str, str]]:
    axes = head.get("rms_after_resolution_per_axis_m")
    if not axes or any(_num(v) is None for v in axes):
        yield "", "no fix after resolution", NO_DATA, ""
        return
    east, north = (float(v) for v in axes)
    yield "", f"σx {_g(east)} m, σy {_g(north)} m", PASS if max(east, north) <= 20.0 else OUTSIDE, ""


# ----- rd_nav (digest 002) ------------------------------------------------------------------------------------


def _rd_errors(head: dict[str, Any], m: dict[str, Any] | None) -> Iterator[tuple[str, str, str, str]]:
    per_auv: dict[str, Any] = head.get("per_auv") or {}
    if not per_auv:
        yield "", "no cycle fix", NO_DATA, ""
        return
    for auv, e in sorted(per_auv.items()):
        mean, sd, mx = e.get("error_mean_m"), e.get("error_sd_m"), _num(e.get("error_max_abs_m"))
        if not mean or mx is None:
            yield auv, "no truth for its fixes", NO_DATA, ""
            continue
        worst_mean = max(abs(float(v)) for v in mean)
        worst_sd = max(float(v) for v in sd) if sd else None
        text = f"|mean| ≤ {_g(worst_mean)} m, SD ≤ {_g(worst_sd) if worst_sd is not None else '—'} m, max {_g(mx)} m"
        ok = worst_mean <= 0.25 and (worst_sd is None or worst_sd <= 0.75) and mx <= 2.0
        note = f"{e.get('cycle_fixes', 0)} cycle fixes" + ("; SD needs 2 or more" if worst_sd is None else "")
        yield auv, text, PASS if ok else OUTSIDE, note


# ----- pcl_tracker (digest 003) -------------------------------------------------------------------------------


def _pcl_pos(head: dict[str, Any], m: dict[str, Any] | None) -> Iterator[tuple[str, str, str, str]]:
    v = _num(head.get("pos_rmse_second_half_m"))
    if v is None:
        yield "", "no confirmed track on a target in the second half of the run", NO_DATA, ""
        return
    yield "", f"{_g(v)} m (second half of the run)", PASS if v < 50.0 else OUTSIDE, ""


def _pcl_vel(head: dict[str, Any], m: dict[str, Any] | None) -> Iterator[tuple[str, str, str, str]]:
    v = _num(head.get("vel_rmse_second_half_mps"))
    if v is None:
        yield "", "no target velocity to compare in the second half of the run", NO_DATA, ""
        return
    yield "", f"{_g(v)} m/s (second half of the run)", PASS if v <= 2.0 else OUTSIDE, ""


# ----- attitude (digest 004) ----------------------------------------------------------------------------------


def _attitude_los(head: dict[str, Any], m: dict[str, Any] | None) -> Iterator[tuple[str, str, str, str]]:
    key = next((k for k in head if k.startswith("los_rms_deg_from_scan_")), None)
    values = head.get(key) if key else None
    if not values or all(_num(v) is None for v in values.values()):
        yield "", "no angle error", NO_DATA, ""
        return
    first = int(key.rsplit("_", 1)[1]) if key else 0
    names = {"psi_los": "ψᴸ", "theta_los": "ϑᴸ", "gamma_los": "γᴸ"}
    text = ", ".join(f"{names.get(k, k)} {_g(float(v))}°" for k, v in values.items() if _num(v) is not None)
    worst = max(float(v) for v in values.values() if _num(v) is not None)
    if first < 40:
        scans = head.get("scans_per_target_max", 0)
        yield (
            "",
            f"{text} (RMS from contact {first})",
            NOT_COMPARABLE,
            f"{scans} contacts per target at most; the paper's figure holds from about the 40th on",
        )
        return
    yield "", f"{text} (RMS from contact {first})", PASS if worst < 10.0 else OUTSIDE, ""


#: terrain_nav's figures (named by its plugin: ``ReportSection(paper="tools.report.paper:TERRAIN_NAV")``)
TERRAIN_NAV: list[PaperFigure] = [
    PaperFigure(
        "correction error of the modified algorithm (with the reliability conditions C1–C4), on both axes, in "
        "map cells; the paper's simulation over SRTM terrain, cells of 125 m, a failure injected",
        "≤ 1 cell (≤ 125 m)",
        "digest 001 §3.2, Fig. 2",
        _terrain_error,
    ),
]

#: lbl_nav's figures (named by its plugin: ``ReportSection(paper="tools.report.paper:LBL_NAV")``)
LBL_NAV: list[PaperFigure] = [
    PaperFigure(
        "which of the two mirror hypotheses is accepted; the paper's Monte-Carlo: two beacons, track 10° to the "
        "beacon line, 1500 runs",
        "the true one in every run (0 of 1500 wrong)",
        "digest 000 §3.1",
        _lbl_decision,
    ),
    PaperFigure(
        "time from launch to resolving the ambiguity; the paper's field data (towed body, 4 m/s)",
        "4 s with buffered data, 16 s without",
        "digest 000 §3.2",
        _lbl_resolution,
    ),
    PaperFigure(
        "RMS position error per axis after resolution; the paper's Monte-Carlo (Fig. 5 б, в)",
        "within 0–20 m",
        "digest 000 §3.1",
        _lbl_rms,
    ),
]

#: rd_nav's figures (named by its plugin: ``ReportSection(paper="tools.report.paper:RD_NAV")``)
RD_NAV: list[PaperFigure] = [
    PaperFigure(
        "particle-filter error per coordinate (signed: mean, standard deviation, largest absolute); the "
        "paper's simulation: 4-h mission, three fixed beacons 2.9–3.0 km apart, 100 runs",
        "mean ≤ 0.25 m, SD ≤ 0.75 m, max ≤ 2 m",
        "digest 002 §5.1",
        _rd_errors,
    ),
]

#: pcl_tracker's figures (named by its plugin: ``ReportSection(paper="tools.report.paper:PCL_TRACKER")``)
PCL_TRACKER: list[PaperFigure] = [
    PaperFigure(
        "steady-state 3-D position RMSE of the tracks; the paper's simulation: one target at 200 m/s, no "
        "clutter, every plot detected, 1000 runs",
        "< 50 m",
        "digest 003 §3.3",
        _pcl_pos,
    ),
    PaperFigure(
        "steady-state velocity RMSE of the tracks (same simulation)",
        "1–2 m/s",
        "digest 003 §3.3",
        _pcl_vel,
    ),
]

#: attitude's figures (named by its plugin: ``ReportSection(paper="tools.report.paper:ATTITUDE")``)
ATTITUDE: list[PaperFigure] = [
    PaperFigure(
        "RMS error of the line-of-sight angles (heading ψᴸ, pitch ϑᴸ, roll γᴸ) after about 40 radar contacts; "
        "the paper's simulation: straight level flight from 100 km, 3074 runs (Fig. 3)",
        "units of degrees (< 10°)",
        "digest 004 §3.5",
        _attitude_los,
    ),
]


def paper_figures() -> dict[str, list[PaperFigure]]:
    """The paper's figures of every estimator kind whose plugin names them (``ReportSection.paper``)."""
    return {name: list(resolve(sec.paper)) for name, sec in report_sections() if sec.paper is not None}


def verdicts(kind: str, instance: str, headline: dict[str, Any], metrics: dict[str, Any] | None) -> list[Verdict]:
    """This run against every figure of the kind's paper (empty for a kind without a paper)."""
    rows = []
    for fig in paper_figures().get(kind, []):
        for subject, this_run, verdict, note in fig.check(headline, metrics):
            rows.append(Verdict(kind, instance, subject, fig.what, fig.paper, this_run, verdict, note, fig.source))
    return rows


def silent_estimators(scenario: Any, outputs: dict[str, Any]) -> list[Verdict]:
    """A row for every estimator the scenario lists whose kind has paper figures but that published nothing in the
    recording: it is named, with no data, instead of missing from the summary (a new user's audit: an rd_nav whose
    vehicle never departed dropped out of the verdicts without a word)."""
    rows = []
    for est in getattr(scenario, "estimators", None) or ():
        figures = paper_figures().get(est.kind, [])
        if figures and not outputs.get(f"{est.kind}/{est.instance}"):
            note = "published nothing in this recording (not running, not started, or its input never came)"
            for fig in figures:
                rows.append(Verdict(est.kind, est.instance, "", fig.what, fig.paper, "—", NO_DATA, note, fig.source))
    return rows


__all__ = [
    "ATTITUDE",
    "LBL_NAV",
    "NOT_COMPARABLE",
    "NO_DATA",
    "OUTSIDE",
    "PASS",
    "PCL_TRACKER",
    "RD_NAV",
    "TERRAIN_NAV",
    "PaperFigure",
    "Verdict",
    "paper_figures",
    "silent_estimators",
    "verdicts",
]
