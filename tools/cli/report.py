"""``fixstream report RECORDING.mcap|DIR ... [--out DIR]``: an evaluation report of a recording.

Writes ``index.html`` (self-contained: plots embedded, opens offline) and ``metrics.json`` to ``--out``
(default ``<recording>_report/`` beside the first file) and prints the page's path. Per estimator found in the
recording: plan view against truth, error against time with ±3σ, NEES with its χ² band and the estimator's own
story; a summary table with the papers' figures on top. The scenario comes from the recording's start marker
(looked up in ``--scenarios-dir``) or ``--scenario``; with it, each estimator's ``fixstream mc`` metrics are
computed from what it published (equal to ``fixstream mc`` on the same scenario, seed and run).

Exit status: 0 written; 2 the recording (or scenario) cannot be used — the message names the file and the
problem (a truncated file: ``--allow-truncated`` reports its readable part).
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", nargs="+", help="MCAP file(s) of one recording, or a directory of them")
    parser.add_argument("--out", help="output directory (default: <recording>_report beside the first file)")
    parser.add_argument("--scenario", help="scenario .yaml (or name) instead of the one the start marker names")
    parser.add_argument(
        "--scenarios-dir", help="where scenario names are looked up (default $FIXSTREAM_SCENARIOS_DIR or scenarios)"
    )
    parser.add_argument("--allow-truncated", action="store_true", help="report the readable part of a truncated file")
    parser.add_argument("--workers", type=int, help="processes drawing the figures (default: the CPUs, at most 4)")
    parser.add_argument("--no-progress", action="store_true", help="no progress output")
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
            progress=not args.no_progress,
            workers=args.workers,
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
