"""The report as one self-contained HTML file: inline CSS, figures as base64 PNG, no script, no network.

Read top-down in a minute: the run's facts, then the **summary** — one row per figure an estimator's paper
reports: what the paper measured (in words), its number, this run's number and a verdict (:mod:`.paper`) — then
one part per estimator: its headline numbers as a table with units, its figures, its notes; the diagnostics last.

Figures are drawn wider than the page column and shown at its width; a click on one shows it at full size
(a CSS checkbox toggle: still no script), scrolling sideways inside its frame.
"""

from __future__ import annotations

import html
import json
from typing import Any

from shared.mcap_io import REJECTED_SCHEMA
from shared.plugins import report_sections

from .paper import NO_DATA, NOT_COMPARABLE, OUTSIDE, PASS, Verdict
from .plots.common import Section

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 1.2em auto; max-width: 1240px;
       color: #222; line-height: 1.4; padding: 0 1.2em; font-size: 15px; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; }
h2 { font-size: 1.3em; border-bottom: 2px solid #36c; padding-bottom: 0.2em; margin-top: 2.2em; }
h3 { font-size: 1.05em; margin: 1.4em 0 0.3em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.55em; vertical-align: top; text-align: left; }
th { background: #eef2fa; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
td.unit { color: #555; white-space: nowrap; }
table.summary { width: 100%; }
table.summary td.est { white-space: nowrap; }
.verdict { font-weight: 600; white-space: nowrap; padding: 0.1em 0.5em; border-radius: 0.8em; }
.v-pass { background: #d8f3dc; color: #1b5e20; }
.v-outside { background: #ffe0db; color: #b71c1c; }
.v-na { background: #eceff1; color: #455a64; }
.small { font-size: 0.85em; color: #555; }
.meta { color: #444; font-size: 0.95em; }
.note { background: #fff7e0; border-left: 4px solid #e0a800; padding: 0.35em 0.7em; margin: 0.4em 0;
        font-size: 0.92em; }
nav.toc { font-size: 0.95em; }
figure { margin: 0.6em 0 1.4em; overflow-x: auto; border: 1px solid #ddd; }
figure img { display: block; width: 100%; height: auto; cursor: zoom-in; }
input.zoom { display: none; }
input.zoom:checked + label img { width: auto; max-width: none; cursor: zoom-out; }
figcaption { font-size: 0.88em; color: #444; padding: 0.3em 0.6em; border-top: 1px solid #eee; }
code { font-size: 0.9em; }
"""


def kind_names() -> dict[str, str]:
    """A readable name per estimator kind (``ReportSection.title`` of its plugin; the section titles say more)."""
    return {name: sec.title for name, sec in report_sections() if sec.title}


#: unit words in metric keys (``horizontal_error_rms_m``) and how the page writes them
_UNITS = {"m": "m", "s": "s", "mps": "m/s", "deg": "°", "rad": "rad", "cells": "cells", "m2": "m²", "hz": "Hz"}
#: abbreviations written as such
_WORDS = {
    "rms": "RMS",
    "rmse": "RMSE",
    "nees": "NEES",
    "ospa": "OSPA",
    "los": "LOS",
    "pos": "position",
    "vel": "velocity",
    "auvs": "AUVs",
    "id": "id",
}
#: keys with their own wording: (label, unit, scale)
_SPECIAL: dict[str, tuple[str, str, float]] = {
    "nees_in_95_band": ("NEES samples inside the two-sided 95 % χ² interval (≈ 95 % if consistent)", "%", 100.0),
    "nees_mean": ("NEES mean (≈ degrees of freedom if consistent)", "", 1.0),
    "nees_dof": ("NEES degrees of freedom (position components)", "", 1.0),
    "false_fixes_over_1_cell": ("false fixes (more than 1 cell off)", "", 1.0),
}


def label_and_unit(key: str) -> tuple[str, str, float]:
    """A metric key as the page writes it: (label, unit, scale), e.g. ``vel_rmse_second_half_mps`` ->
    ("velocity RMSE second half", "m/s", 1)."""
    if key in _SPECIAL:
        return _SPECIAL[key]
    words = key.split("_")
    unit = ""
    for i in range(len(words) - 1, -1, -1):
        if words[i] in _UNITS:
            unit = _UNITS[words.pop(i)]
            break
    return " ".join(_WORDS.get(w, w) for w in words), unit, 1.0


def fmt(value: Any, scale: float = 1.0) -> str:
    """A value as text: 4 significant digits, lists and mappings inline, None as a dash."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float | int) and scale != 1.0:
        value = float(value) * scale
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, dict):
        return " · ".join(f"{k} {fmt(v)}" for k, v in value.items())
    if isinstance(value, list | tuple):
        return ", ".join(fmt(v) for v in value)
    return "—" if value is None else str(value)


def _is_table(value: Any) -> bool:
    return isinstance(value, dict) and bool(value) and all(isinstance(x, dict) for x in value.values())


def headline_table(headline: dict[str, Any]) -> str:
    """The headline numbers: quantity, value, unit; a mapping of mappings (per AUV) as a table of its own."""
    e = html.escape
    rows, subtables = [], []
    for key, value in headline.items():
        if _is_table(value):
            subtables.append(_subtable(key, value))
            continue
        label, unit, scale = label_and_unit(key)
        rows.append(
            f"<tr><td>{e(label)}</td><td class='num'>{e(fmt(value, scale))}</td><td class='unit'>{e(unit)}</td></tr>"
        )
    head = "<table><tr><th>quantity</th><th>value</th><th>unit</th></tr>" + "".join(rows) + "</table>"
    return head + "".join(subtables)


def _subtable(key: str, rows: dict[str, dict[str, Any]]) -> str:
    e = html.escape
    cols = list(dict.fromkeys(k for r in rows.values() for k in r))
    names = [label_and_unit(c) for c in cols]
    header = "".join(f"<th>{e(lbl)}{f', {e(u)}' if u else ''}</th>" for lbl, u, _ in names)
    body = "".join(
        f"<tr><td>{e(name)}</td>"
        + "".join(f"<td class='num'>{e(fmt(r.get(c), sc))}</td>" for c, (_, _, sc) in zip(cols, names, strict=True))
        + "</tr>"
        for name, r in rows.items()
    )
    first = key.removeprefix("per_").replace("_", " ")
    return f"<table><tr><th>{e(first)}</th>{header}</tr>{body}</table>"


def _badge(verdict: str) -> str:
    cls = {PASS: "v-pass", OUTSIDE: "v-outside"}.get(verdict, "v-na")
    return f"<span class='verdict {cls}'>{html.escape(verdict)}</span>"


def summary_table(sections: list[Section], verdicts: list[Verdict]) -> str:
    """One row per paper figure and platform; the estimator cell spans its rows."""
    e = html.escape
    out = [
        "<table class='summary'><tr><th>estimator</th><th>what the paper reports</th><th>the paper's figure</th>"
        "<th>this run</th><th>verdict</th></tr>"
    ]
    names = kind_names()
    for i, s in enumerate(sections):
        rows = [v for v in verdicts if v.kind == s.kind and v.instance == s.instance]
        name = names.get(s.kind, s.kind)
        est = (
            f"<a href='#s{i}'>{e(name)}</a><br><span class='small'>{e(s.kind)} / {e(s.instance)}</span>"
            if rows or s.kind in names
            else f"<a href='#s{i}'>{e(s.kind)}</a><br><span class='small'>{e(s.instance)}</span>"
        )
        if not rows:
            out.append(f"<tr><td class='est'>{est}</td><td colspan='4' class='small'>no paper figure</td></tr>")
            continue
        for k, v in enumerate(rows):
            cells = f"<td class='est' rowspan='{len(rows)}'>{est}</td>" if k == 0 else ""
            same = (v.what, v.paper)
            if k == 0 or (rows[k - 1].what, rows[k - 1].paper) != same:  # one cell for a figure's platforms
                span = 1
                while k + span < len(rows) and (rows[k + span].what, rows[k + span].paper) == same:
                    span += 1
                cells += f"<td rowspan='{span}'>{e(v.what)}</td><td rowspan='{span}'><b>{e(v.paper)}</b></td>"
            run = (f"<b>{e(v.subject)}</b>: " if v.subject else "") + e(v.this_run)
            if v.note:
                run += f"<br><span class='small'>{e(v.note)}</span>"
            out.append(f"<tr>{cells}<td>{run}</td><td>{_badge(v.verdict)}</td></tr>")
    if not sections:
        out.append("<tr><td colspan='5'>no estimator output in this recording</td></tr>")
    out.append("</table>")
    counts = {k: sum(1 for v in verdicts if v.verdict == k) for k in (PASS, OUTSIDE, NOT_COMPARABLE, NO_DATA)}
    tally = ", ".join(f"{n} {k}" for k, n in counts.items() if n)
    if tally:
        out.append(
            f"<p class='small'>{e(tally)}. One run is a sanity check, not a reproduction of a Monte-Carlo figure: "
            "<code>fixstream mc</code> does the statistics.</p>"
        )
    return "".join(out)


def _run_facts(run: dict[str, Any]) -> str:
    e = html.escape
    files = run.get("files", [])
    scenario = run.get("scenario") or "unknown"
    origin = run.get("scenario_file")
    parts = [
        f"recording <b>{e(', '.join(files))}</b>",
        f"{e(fmt(run.get('messages')))} messages, {float(run.get('t_end_s') or 0.0):.1f} s of data",
        f"scenario <b>{e(str(scenario))}</b>" + (f" ({e(origin)})" if origin else " (no scenario file)"),
        f"seed {e(fmt(run.get('seed')))}",
    ]
    if (run.get("recorder_run") or 1) > 1:
        parts.append(f"the recorder's run {e(fmt(run.get('recorder_run')))} of this scenario")
    return "<p class='meta'>" + " · ".join(parts) + "</p>"


def _figure(index: str, fig: Any) -> str:
    e = html.escape
    return (
        f"<h3>{e(fig.title)}</h3><figure><input type='checkbox' class='zoom' id='z{index}'>"
        f"<label for='z{index}' title='click: full size / back'>"
        f"<img alt='{e(fig.title)}' src='data:image/png;base64,{fig.png_b64}'></label>"
        + (f"<figcaption>{e(fig.caption)}</figcaption>" if fig.caption else "")
        + "</figure>"
    )


def render_html(report: dict[str, Any], sections: list[Section], verdicts: list[Verdict]) -> str:
    """The whole page: run facts, the summary with the verdicts, one part per section, the diagnostics."""
    e = html.escape
    run = report["run"]
    title = str(run.get("scenario") or "recording")
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        "<meta name='viewport' content='width=device-width, initial-scale=1'>",
        "<link rel='icon' href='data:,'>",
        f"<title>fixstream report — {e(title)}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>fixstream report — {e(str(run.get('scenario') or 'unknown scenario'))}</h1>",
        _run_facts(run),
    ]
    for note in report.get("notes", []):
        parts.append(f"<div class='note'>{e(note)}</div>")
    parts.append("<h2 id='summary'>Summary: this run against the papers' figures</h2>")
    parts.append(summary_table(sections, verdicts))
    plugin = report.get("estimators", {})
    if plugin:
        bad = {inst: entry for inst, entry in plugin.items() if entry.get("status") != "ok"}
        ok = len(plugin) - len(bad)
        parts.append(
            f"<p class='small'>Monte-Carlo metrics (the <code>fixstream mc</code> plugins on this recording): "
            f"{ok} of {len(plugin)} estimators scored, in <code>metrics.json</code> beside this page.</p>"
        )
        for inst, entry in bad.items():
            parts.append(
                f"<div class='note'>{e(inst)} ({e(entry.get('kind', ''))}): {e(str(entry.get('status')))}</div>"
            )
    if sections:
        names = kind_names()
        links = " · ".join(
            f"<a href='#s{i}'>{e(names.get(s.kind, s.kind))} {e(s.instance)}</a>" for i, s in enumerate(sections)
        )
        parts.append(f"<nav class='toc'>Sections: {links} · <a href='#diagnostics'>diagnostics</a></nav>")
    for i, s in enumerate(sections):
        parts.append(f"<h2 id='s{i}'>{e(s.title)}</h2>")
        for note in s.notes:
            parts.append(f"<div class='note'>{e(note)}</div>")
        parts.append(headline_table(s.headline))
        for caption, header, rows in s.tables:
            parts.append(f"<table><caption>{e(caption)}</caption><tr>")
            parts.append("".join(f"<th>{e(h)}</th>" for h in header) + "</tr>")
            for row in rows:
                parts.append("<tr>" + "".join(f"<td>{e(fmt(c))}</td>" for c in row) + "</tr>")
            parts.append("</table>")
        for k, fig in enumerate(s.figures):
            parts.append(_figure(f"{i}-{k}", fig))
    diags = report.get("diagnostics", {})
    parts.append("<h2 id='diagnostics'>Diagnostics: each service's counts by reason</h2>")
    if diags:
        parts.append("<table><tr><th>service / instance</th><th>reason: count (the last running totals)</th></tr>")
        for src, counts in sorted(diags.items()):
            parts.append(f"<tr><td>{e(src)}</td><td>{e(fmt(counts))}</td></tr>")
        parts.append("</table>")
    else:
        parts.append("<p class='small'>no diagnostic message in the recording</p>")
    rejected = report.get("foreign_channels", {}).get(REJECTED_SCHEMA, 0)
    if rejected:
        parts.append(
            f"<p>The recorder kept <b>{rejected}</b> payloads that failed decoding or validation, byte for byte, on "
            "<code>fixstream/rejected/&lt;key&gt;</code> (<code>fixstream info</code> lists them by key; "
            "<code>fixstream play</code> puts them back on their keys).</p>"
        )
    parts.append(
        "<p class='small'>generated by <code>fixstream report</code>; records on other channels skipped: "
        f"{e(json.dumps(report.get('foreign_channels', {})))}</p>"
    )
    parts.append("</body></html>\n")
    return "\n".join(parts)


__all__ = ["fmt", "headline_table", "label_and_unit", "render_html", "summary_table"]
