"""``fixstream report RECORDING.mcap|DIR [--out DIR]``: an evaluation report of one recording.

Writes ``index.html`` (self-contained: plots embedded, opens offline) and ``metrics.json`` to ``--out``
(default ``<recording>_report/`` beside the first file) and prints their paths. On top, a verdict per estimator
against its paper's figure; then per estimator found in the recording: plan views against truth (the whole
scene and each track zoomed), error against time with ±3σ per platform, NEES with its χ² band and the
estimator's own story.

One recording per report: a directory means its newest recording (a note names the others); several files must
be the rotated parts of one recording. ``--all`` merges several recordings into one report.

The scenario: ``--scenario``; else the one attached to the recording (so the file alone, copied anywhere, gives
the same report); else the start marker's name looked up in ``--scenarios-dir``. With it, each estimator's
``fixstream mc`` metrics are computed from what it published (equal to ``fixstream mc`` on the same scenario,
seed and run).

Progress bars go to stderr when it is a terminal (``--progress``: always, ``--no-progress``: never).

Exit status: 0 written; 2 the recording (or scenario) cannot be used, or several recordings without ``--all`` —
the message names the file(s) and the problem (a truncated file: ``--allow-truncated`` reports its readable part).
"""

from __future__ import annotations

import argparse

from . import progress
from .common import positive_int


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "recording", nargs="+", help="an MCAP file (or the rotated files of one recording), or a directory"
    )
    parser.add_argument("--out", help="output directory (default: <recording>_report beside the first file)")
    parser.add_argument(
        "--all",
        "--merge",
        dest="merge",
        action="store_true",
        help="merge every recording given (or in the directory) into one report (default: one recording, the newest)",
    )
    parser.add_argument(
        "--scenario", help="scenario .yaml (or name) instead of the one the recording carries or its marker names"
    )
    parser.add_argument(
        "--scenarios-dir", help="where scenario names are looked up (default $FIXSTREAM_SCENARIOS_DIR or scenarios)"
    )
    parser.add_argument("--allow-truncated", action="store_true", help="report the readable part of a truncated file")
    parser.add_argument(
        "--workers", type=positive_int, help="processes drawing the figures (default: the CPUs, at most 4)"
    )
    progress.add_arguments(parser, "the progress bars")
    parser.add_argument("--timings", action="store_true", help="print the time of each stage")


def run(args: argparse.Namespace) -> int:
    import sys

    from tools.report import ReportError, make_report

    try:
        result = make_report(
            args.recording,
            args.out,
            scenario=args.scenario,
            scenarios_dir=args.scenarios_dir,
            allow_truncated=args.allow_truncated,
            progress=progress.wanted(args.progress),
            workers=args.workers,
            merge=args.merge,
        )
    except ReportError as exc:
        print(f"fixstream report: {exc}", file=sys.stderr)
        return 2
    if args.timings:
        print(" ".join(f"{k}={v:.2f}" for k, v in result.timings_s.items()), file=sys.stderr)
    for note in result.metrics.get("notes", []):
        print(f"note: {note}", file=sys.stderr)
    print(f"report: {result.html_path}", flush=True)
    print(f"metrics: {result.metrics_path}", flush=True)
    return 0
