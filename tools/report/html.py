"""The report as one self-contained HTML file: inline CSS, figures as base64 PNG, no script, no network."""

from __future__ import annotations

import html
import json
from typing import Any

from .paper import PAPER
from .plots.common import Section

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 1.5em auto; max-width: 1100px;
       color: #222; line-height: 1.35; padding: 0 1em; }
h1 { font-size: 1.5em; margin-bottom: 0.2em; }
h2 { font-size: 1.2em; border-bottom: 2px solid #36c; padding-bottom: 0.2em; margin-top: 2em; }
h3 { font-size: 1.0em; margin: 1.2em 0 0.3em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.85em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.5em; vertical-align: top; text-align: left; }
th { background: #eef2fa; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
.meta { color: #555; font-size: 0.85em; }
.note { background: #fff7e0; border-left: 4px solid #e0a800; padding: 0.3em 0.6em; margin: 0.4em 0; font-size: 0.85em; }
figure { margin: 1em 0; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.8em; color: #555; }
code { font-size: 0.9em; }
ul.kv { margin: 0; padding-left: 1.1em; }
"""


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, dict):
        return ", ".join(f"{k}: {_fmt(v)}" for k, v in value.items())
    if isinstance(value, list):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    return "—" if value is None else str(value)


def _kv(d: dict[str, Any]) -> str:
    items = []
    for k, v in d.items():
        if isinstance(v, dict) and v and all(isinstance(x, dict) for x in v.values()):
            inner = "".join(f"<li>{html.escape(str(kk))}: {html.escape(_fmt(vv))}</li>" for kk, vv in v.items())
            items.append(f"<li>{html.escape(k)}:<ul class='kv'>{inner}</ul></li>")
        else:
            items.append(f"<li>{html.escape(k.replace('_', ' '))}: <b>{html.escape(_fmt(v))}</b></li>")
    return f"<ul class='kv'>{''.join(items)}</ul>"


def _paper(kind: str) -> str:
    rows = PAPER.get(kind, [])
    if not rows:
        return "—"
    return (
        "<ul class='kv'>"
        + "".join(
            f"<li>{html.escape(what)}: <b>{html.escape(fig)}</b> <span class='meta'>({html.escape(src)})</span></li>"
            for what, fig, src in rows
        )
        + "</ul>"
    )


def render_html(report: dict[str, Any], sections: list[Section]) -> str:
    """The whole page: title and run facts, the summary table, one part per section, the run's diagnostics."""
    e = html.escape
    run = report["run"]
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        "<meta name='viewport' content='width=device-width, initial-scale=1'>",
        "<link rel='icon' href='data:,'>",
        f"<title>fixstream report — {e(str(run.get('scenario') or 'recording'))}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>fixstream report — {e(str(run.get('scenario') or 'unknown scenario'))}</h1>",
        "<p class='meta'>"
        + " · ".join(
            e(f"{k}: {_fmt(v)}")
            for k, v in (
                ("seed", run.get("seed")),
                ("scenario file", run.get("scenario_file")),
                ("messages", run.get("messages")),
                ("data span", f"{run.get('t_end_s', 0):.1f} s"),
                ("files", ", ".join(run.get("files", []))),
            )
        )
        + "</p>",
    ]
    for note in report.get("notes", []):
        parts.append(f"<div class='note'>{e(note)}</div>")
    parts.append("<h2 id='summary'>Summary</h2>")
    parts.append("<table><tr><th>estimator</th><th>this run</th><th>the paper</th></tr>")
    for i, s in enumerate(sections):
        head = {k: v for k, v in s.headline.items() if k != "per_auv"}
        parts.append(
            f"<tr><td><a href='#s{i}'>{e(s.kind)}</a><br><span class='meta'>{e(s.instance)}</span></td>"
            f"<td>{_kv(head)}</td><td>{_paper(s.kind)}</td></tr>"
        )
    if not sections:
        parts.append("<tr><td colspan='3'>no estimator output in this recording</td></tr>")
    parts.append("</table>")
    plugin = report.get("estimators", {})
    if plugin:
        parts.append("<h3>Monte-Carlo metrics (the <code>fixstream mc</code> plugins on this recording)</h3><table>")
        parts.append("<tr><th>instance</th><th>kind</th><th>status</th></tr>")
        for inst, entry in plugin.items():
            parts.append(
                f"<tr><td>{e(inst)}</td><td>{e(entry.get('kind', ''))}</td><td>{e(str(entry.get('status')))}</td></tr>"
            )
        parts.append("</table><p class='meta'>the figures are in metrics.json beside this page</p>")
    for i, s in enumerate(sections):
        parts.append(f"<h2 id='s{i}'>{e(s.title)}</h2>")
        for note in s.notes:
            parts.append(f"<div class='note'>{e(note)}</div>")
        parts.append(_kv(s.headline))
        for caption, header, rows in s.tables:
            parts.append(f"<table><caption>{e(caption)}</caption><tr>")
            parts.append("".join(f"<th>{e(h)}</th>" for h in header) + "</tr>")
            for row in rows:
                parts.append("<tr>" + "".join(f"<td>{e(_fmt(c))}</td>" for c in row) + "</tr>")
            parts.append("</table>")
        for fig in s.figures:
            parts.append(
                f"<figure><h3>{e(fig.title)}</h3><img alt='{e(fig.title)}' src='data:image/png;base64,{fig.png_b64}'>"
                + (f"<figcaption>{e(fig.caption)}</figcaption>" if fig.caption else "")
                + "</figure>"
            )
    diags = report.get("diagnostics", {})
    if diags:
        parts.append("<h2 id='diagnostics'>Diagnostics (last running counts per service)</h2><table>")
        parts.append("<tr><th>service</th><th>reason: count</th></tr>")
        for src, counts in sorted(diags.items()):
            parts.append(f"<tr><td>{e(src)}</td><td>{e(_fmt(counts))}</td></tr>")
        parts.append("</table>")
    parts.append(
        "<p class='meta'>generated by <code>fixstream report</code>; "
        f"foreign channels skipped: {e(json.dumps(report.get('foreign_channels', {})))}</p>"
    )
    parts.append("</body></html>\n")
    return "\n".join(parts)


__all__ = ["render_html"]
