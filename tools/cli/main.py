"""``fixstream`` entry point. Each sub-command lives in ``tools/cli/<name>.py`` with
``add_arguments(parser)`` and ``run(args) -> int``; heavy imports happen inside ``run``."""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from pydantic import ValidationError

from shared.errors import StartupError
from shared.settings import settings_error_message

#: sub-command -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "router": ("tools.cli.router", "run a Zenoh router (the embedded default for local stacks)"),
    "run": ("tools.cli.run", "run a service by name (recorder, lbl_nav, ...)"),
    "play": ("tools.cli.play", "play a scenario YAML or replay an MCAP recording onto Zenoh"),
    "record": ("tools.cli.record", "record Zenoh streams to MCAP"),
    "info": ("tools.cli.info", "what a recording holds (like ros2 bag info); --recover finalises a killed one"),
    "echo": ("tools.cli.echo", "print decoded messages on a key expression"),
    "status": ("tools.cli.status", "query every service's status"),
    "scenarios": ("tools.cli.scenarios", "list, show and validate scenario files"),
    "mc": ("tools.cli.mc", "Monte-Carlo runs of a scenario in-process, metrics to JSON"),
    "up": ("tools.cli.up", "run the compose.yaml stack as local processes"),
    "report": ("tools.cli.report", "evaluation report of a recording: HTML with plots + metrics JSON"),
    "foxglove": ("tools.cli.foxglove", "live bridge: Zenoh streams to the Foxglove app over WebSocket"),
    "pki": ("tools.cli.pki", "certificates for the secure stack (mutual TLS, one identity per role)"),
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
