"""``fixstream`` entry point. Each sub-command lives in ``shared/cli/<name>.py`` with
``add_arguments(parser)`` and ``run(args) -> int``; heavy imports happen inside ``run``."""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from pydantic import ValidationError

from ..errors import StartupError
from ..settings import settings_error_message

#: sub-command -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "router": ("shared.cli.router", "run a Zenoh router (the embedded default for local stacks)"),
    "run": ("shared.cli.run", "run a service by name (recorder, lbl_nav, ...)"),
    "play": ("shared.cli.play", "play a scenario YAML or replay an MCAP recording onto Zenoh"),
    "record": ("shared.cli.record", "record Zenoh streams to MCAP"),
    "info": ("shared.cli.info", "what a recording holds (like ros2 bag info); --recover finalises a killed one"),
    "echo": ("shared.cli.echo", "print decoded messages on a key expression"),
    "status": ("shared.cli.status", "query every service's status"),
    "scenarios": ("shared.cli.scenarios", "list, show and validate scenario files"),
    "mc": ("shared.cli.mc", "Monte-Carlo runs of a scenario in-process, metrics to JSON"),
    "up": ("shared.cli.up", "run the compose.yaml stack as local processes"),
    "report": ("shared.cli.report", "evaluation report of a recording: HTML with plots + metrics JSON"),
    "foxglove": ("shared.cli.foxglove", "live bridge: Zenoh streams to the Foxglove app over WebSocket"),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The full parser; only ``command``'s module is imported (all of them when None)."""
    parser = argparse.ArgumentParser(prog="fixstream", description="fixstream navigation and tracking stack")
    parser.add_argument("--log-level", default=os.environ.get("FIXSTREAM_LOG_LEVEL", "INFO"))
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (module_name, help_text) in COMMANDS.items():
        if command is not None and name != command:
            sub.add_parser(name, help=help_text)
            continue
        module = importlib.import_module(module_name)
        p = sub.add_parser(name, help=help_text, description=(module.__doc__ or help_text).strip())
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in argv if a in COMMANDS), None)
    args = build_parser(command).parse_args(argv)
    logging.basicConfig(
        level=getattr(logging, str(args.log_level).upper(), logging.INFO),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        return 130
    except StartupError as exc:
        print(f"fixstream {args.command}: {exc}", file=sys.stderr)
        return 2
    except ValidationError as exc:  # settings built outside ServiceSettings.load (e.g. ZenohSettings)
        print(f"fixstream {args.command}: {settings_error_message(exc)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
