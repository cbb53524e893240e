"""``fixstream up``: run the compose.yaml stack as local processes.

Reads the compose file (default: compose.yaml here or in a parent directory), interpolates variables
as compose does (the process environment over ``.env``), replaces the ``eclipse/zenoh`` router with an
embedded ``fixstream router`` on loopback (port 7447, as compose publishes it, when free; else a free port, said
on the console), leaves the router's endpoint where clients look (:mod:`shared.local_stack`), and starts every
other service's command locally in depends_on order. Output lines are prefixed with the service name. When the
driver service (label ``fixstream.role: driver``, the player) exits, or on Ctrl-C, the others are stopped with
SIGTERM in reverse order; the MCAP files the run's recorder wrote are listed at the end (none: exit code 1).
With ``--report`` (``make demo``) the run's recording is then reported (``fixstream report``: HTML and metrics
JSON in ``<recording>_report/``) and the page's path printed.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from .common import seconds

if TYPE_CHECKING:
    from ..stack.console import Console

#: interpolation variable that compose.yaml uses for the host side of the recordings volume
RECORDINGS_VAR = "FIXSTREAM_RECORDINGS"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("services", nargs="*", metavar="SERVICE", help="only these (and their dependencies)")
    parser.add_argument("-f", "--file", type=Path, help="compose file (default: compose.yaml, searched upwards)")
    parser.add_argument("--env-file", type=Path, help="variables for interpolation (default: .env beside the file)")
    parser.add_argument(
        "-t", "--timeout", type=seconds, help="seconds each service gets to stop before SIGKILL (default: 10)"
    )
    parser.add_argument("--ready-timeout", type=seconds, default=60.0, help="seconds to wait for a dependency")
    parser.add_argument(
        "--recordings", type=Path, help=f"host directory for recordings (sets ${RECORDINGS_VAR}; default ./recordings)"
    )
    parser.add_argument(
        "--drain",
        type=seconds,
        default=30.0,
        help="at most this many seconds, after the driver's end, for the stack to settle before it is stopped (every "
        "service's inbox empty and nothing more arriving: the recording then holds the whole run); 0: stop at once",
    )
    parser.add_argument("--profile", action="append", default=[], help="enable services of this compose profile")
    parser.add_argument(
        "--router-port",
        type=int,
        help="the embedded router's loopback port, an error when it is in use (default: $FIXSTREAM_ROUTER_PORT, the"
        " same; else 7447 when free, else any free port; 0: any free port). Clients started with no --connect find"
        " it either way",
    )
    parser.add_argument(
        "--secure",
        action="store_true",
        help="run over mutual TLS with a certificate per identity (made for this run) and the router's access control"
        " (tools/stack/router-secure.json5): only the player feeds sensors and markers, only an estimator writes its"
        " fixes; clients started with no flags attach read-only",
    )
    parser.add_argument("--dry-run", action="store_true", help="print the local commands and exit")
    parser.add_argument("--no-color", action="store_true", help="no colours in the service prefixes")
    parser.add_argument(
        "--report",
        action="store_true",
        help="after a successful run, write the report of its recording (fixstream report) and print its path",
    )


def run(args: argparse.Namespace) -> int:
    from shared import local_stack

    from ..stack import ComposeError, Supervisor, find_compose_file, load_compose, plan_stack
    from ..stack.console import Console

    console = Console(color=False if args.no_color else None)
    overrides: dict[str, str] = {}
    if args.recordings is not None:
        overrides[RECORDINGS_VAR] = str(args.recordings.expanduser().resolve())
    profiles = [*args.profile, *filter(None, os.environ.get("COMPOSE_PROFILES", "").split(","))]
    # the port is chosen and announced under a lock that every fixstream up of this user takes: two started at once
    # would otherwise both find 7447 free before either router listens (the second router then fails to bind)
    with local_stack.exclusive():
        try:
            path = args.file or find_compose_file(Path.cwd())
            project = load_compose(path, env_file=args.env_file, overrides=overrides)
            for warning in project.warnings:
                console.event(f"warning: {warning}")
            names = project.select(args.services, profiles)
            pki = None
            if args.secure:
                from ..stack.pki import make_pki

                pki = make_pki(Path(tempfile.mkdtemp(prefix="fixstream-pki-")))
            plan = plan_stack(
                project,
                names,
                stop_timeout=args.timeout,
                create_dirs=not args.dry_run,
                router_port=args.router_port,
                secure=pki,
            )
            if pki is not None:
                plan.temp_dirs.append(pki.directory)
        except (ComposeError, OSError) as exc:
            console.event(f"error: {exc}")
            if not (sys.stdout.isatty() and sys.stderr.isatty()):  # the one line on stderr too (unless one terminal)
                print(f"fixstream up: {exc}", file=sys.stderr)
            return 2
        console.event(f"{project.path}: {', '.join(names)}")
        if args.dry_run:
            for proc in plan.processes:
                changed = {k: v for k, v in proc.env.items() if os.environ.get(k) != v}
                console.event(f"{proc.service}: cd {proc.cwd} && {' '.join(proc.argv)}")
                for key, value in sorted(changed.items()):
                    console.event(f"{proc.service}:   {key}={value}")
            return 0
        announcement = None
        if plan.endpoint is not None:
            announcement = local_stack.announce(plan.endpoint, str(project.path), plan.client_tls)
            console.event(
                f"router on {plan.endpoint}; clients (fixstream echo, status, record, ...) attach with no flags"
            )
    try:
        result = Supervisor(plan, console, ready_timeout=args.ready_timeout, drain=args.drain).run()
    finally:
        if announcement is not None:
            local_stack.withdraw(announcement)
    for rec in result.recordings:
        console.event(f"recording: {rec} ({rec.stat().st_size} bytes)")
    if not result.recordings and plan.output_dirs and not result.recorders:
        console.event(f"no new MCAP file in {', '.join(str(d) for d in plan.output_dirs)}")
    for failure in result.failures:
        console.event(f"failed: {failure}")
    if args.report and result.exit_code == 0 and result.recordings:
        report_path = _report(result.recordings, console)
        if report_path is None:
            console.event("done, exit code 1 (the report failed)")
            return 1
    console.event(f"done, exit code {result.exit_code}")
    return result.exit_code


def _report(recordings: list[Path], console: Console) -> Path | None:
    """``fixstream report`` of the run's recording; prints where it is (None: it failed, the reason printed)."""
    from tools.report import ReportError, make_report

    event = console.event
    try:
        result = make_report(recordings, progress=False, workers=1)  # no fork of a process that ran Zenoh
    except ReportError as exc:
        event(f"report failed: {exc}")
        return None
    for note in result.metrics.get("notes", []):
        event(f"report note: {note}")
    event(f"report: {result.html_path}")
    return result.html_path
