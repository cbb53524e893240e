"""``fixstream report``: an evaluation report of a recording — self-contained HTML and a JSON of its metrics.

Pipeline (one module each):

1. :mod:`.reading` — the MCAP file(s) to decoded messages, with progress; clear errors for bad files;
2. :mod:`.data` — the scenario (start marker or ``--scenario``), events, outputs per publisher, diagnostics,
   truth in one frame (:mod:`shared.foxglove.frames`);
3. :mod:`.metrics` — each estimator's ``fixstream mc`` plugin (``run_metrics``) on what it published, so the
   JSON equals ``fixstream mc`` for the same scenario, seed and run;
4. :mod:`.plots` — one module per estimator, named by its plugin (``Plugin.report``): plan views (the scene and
   each track zoomed), error with ±3σ per platform, NEES with its χ² band, and the estimator's own story;
   headline numbers;
5. :mod:`.paper` — each headline against the figures the estimator's paper reports: pass / outside;
6. :mod:`.html` — the page.

The scenario and the run's facts come from the recording itself when it carries them (:mod:`.carried`), so a
recording copied anywhere gives the same report.

``metrics.json``: ``run`` (file names, scenario and where it came from, seed, the recorder's run count, counts),
``estimators`` (per scenario instance: kind, source, status and the plugin's ``metrics``), ``sections`` (per
section: kind, instance, headline), ``verdicts`` (per paper figure: what, the paper's number, this run's, the verdict),
``diagnostics`` (per service, the last running counts of its diagnostics), ``notes``, ``foreign_channels``.
"""

from __future__ import annotations

import gc
import json
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .reading import ReportError

INDEX = "index.html"
METRICS = "metrics.json"


@dataclass
class ReportResult:
    html_path: Path
    metrics_path: Path
    metrics: dict[str, Any]
    timings_s: dict[str, float]


def default_out_dir(files: Sequence[Path]) -> Path:
    """``<first file without .mcap>_report/`` beside the recording."""
    first = files[0]
    return first.parent / f"{first.stem}_report" if first.is_file() else first / "report"


def make_report(
    paths: Sequence[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str] | None = None,
    *,
    scenario: str | os.PathLike[str] | None = None,
    scenarios_dir: str | os.PathLike[str] | None = None,
    allow_truncated: bool = False,
    progress: bool = True,
    workers: int | None = None,
    merge: bool = False,
) -> ReportResult:
    """Read, compute, plot and write ``index.html`` and ``metrics.json`` (raises :class:`ReportError`).

    One recording per report: a directory means its newest recording, several files must be one recording's
    rotated parts, unless ``merge`` (``--all``; :func:`.reading.select_recording`). The sections are drawn by up
    to ``workers`` processes (default: the CPUs, at most 4; forked, so they share the decoded recording; 1 or a
    platform without ``fork``: in this process)."""
    from .carried import read_carried
    from .reading import read_recording, select_recording

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    files, selection_notes = select_recording(paths, merge=merge)
    rec = read_recording(files, allow_truncated=allow_truncated, progress=progress, merge=merge)
    rec.notes[:0] = selection_notes
    carried = read_carried(files)
    timings["read_s"] = time.perf_counter() - t0
    gc.freeze()  # the decoded messages live to the end: keep the collector from rescanning them
    try:
        return _report(rec, carried, files, out_dir, scenario, scenarios_dir, progress, timings, t0, workers)
    finally:
        gc.unfreeze()


def _report(
    rec: Any,
    carried: Any,
    files: list[Path],
    out_dir: str | os.PathLike[str] | None,
    scenario: str | os.PathLike[str] | None,
    scenarios_dir: str | os.PathLike[str] | None,
    progress: bool,
    timings: dict[str, float],
    t0: float,
    workers: int | None,
) -> ReportResult:
    from tools.montecarlo import jsonable

    from .data import run_data
    from .html import render_html
    from .metrics import plugin_metrics
    from .paper import silent_estimators, verdicts
    from .plots import section_names

    t = time.perf_counter()
    data = run_data(rec, scenario, scenarios_dir, carried)
    metrics = plugin_metrics(data)
    timings["metrics_s"] = time.perf_counter() - t
    t = time.perf_counter()
    names = section_names()
    if progress:
        print(f"plotting {len(data.outputs)} publishers", file=sys.stderr, flush=True)
    sections: list[Any] = []
    for built, note in _build_sections(names, data, metrics, workers):
        sections += built
        if note:
            data.notes.append(note)
    timings["plots_s"] = time.perf_counter() - t
    rows = [
        v
        for sec in sections
        for v in verdicts(sec.kind, sec.instance, sec.headline, (metrics.get(sec.instance) or {}).get("metrics"))
    ]
    rows += silent_estimators(data.scenario, data.outputs)
    report: dict[str, Any] = {
        "run": {
            "files": [f.name for f in files],
            "scenario": data.scenario_name,
            "scenario_file": data.scenario_origin,
            "seed": data.seed,
            "recorder_run": data.run_index,
            "metadata": carried.metadata_names,
            "messages": len(rec.items),
            "events": len(data.events),
            "t_end_s": data.t_end_s,
            "publishers": {src: len(out) for src, out in sorted(data.outputs.items())},
        },
        "estimators": metrics,
        "sections": [{"kind": s.kind, "instance": s.instance, "headline": s.headline} for s in sections],
        "verdicts": [v.as_json() for v in rows],
        "diagnostics": data.diagnostics,
        "notes": data.notes,
        "foreign_channels": dict(rec.foreign),
    }
    report = jsonable(report)
    out = Path(out_dir) if out_dir is not None else default_out_dir(files)
    try:
        out.mkdir(parents=True, exist_ok=True)
        metrics_path = out / METRICS
        metrics_path.write_text(json.dumps(report, indent=2, sort_keys=True, allow_nan=False) + "\n")
        html_path = out / INDEX
        html_path.write_text(render_html(report, sections, rows))
    except OSError as exc:
        raise ReportError(f"{out}: cannot write the report: {exc.strerror or exc}") from None
    timings["total_s"] = time.perf_counter() - t0
    return ReportResult(html_path, metrics_path, report, timings)


#: what the forked section workers read (set just before the pool forks)
_SHARED: tuple[Any, Any] | None = None


def _build_one(name: str, data: Any = None, metrics: Any = None) -> tuple[list[Any], str | None]:
    """One section module's sections, or a note saying why it failed (one failure must not lose the report)."""
    import importlib

    if data is None:
        assert _SHARED is not None
        data, metrics = _SHARED
    try:
        return importlib.import_module(name).build(data, metrics), None
    except Exception as exc:
        return [], f"the {name.rsplit('.', 1)[-1]} section failed: {type(exc).__name__}: {exc}"


def _build_sections(
    names: list[str], data: Any, metrics: Any, workers: int | None
) -> list[tuple[list[Any], str | None]]:
    """Every module's sections, in ``names`` order; in forked workers when more than one CPU is there."""
    import multiprocessing

    n = min(workers or min(os.cpu_count() or 1, 4), len(names))
    if n <= 1 or "fork" not in multiprocessing.get_all_start_methods():
        return [_build_one(name, data, metrics) for name in names]
    from .plots import drawing_order

    global _SHARED
    order = drawing_order(names)
    _SHARED = (data, metrics)
    try:
        with multiprocessing.get_context("fork").Pool(n) as pool:
            done = dict(zip(order, pool.map(_build_one, order, chunksize=1), strict=True))
    except Exception:  # a pool that cannot start or a worker that died: draw them here
        return [_build_one(name, data, metrics) for name in names]
    finally:
        _SHARED = None
    return [done[name] for name in names]


__all__ = ["INDEX", "METRICS", "ReportError", "ReportResult", "default_out_dir", "make_report"]
