"""``fixstream`` entry point. Each sub-command lives in ``tools/cli/<name>.py`` with
``add_arguments(parser)`` and ``run(args) -> int``; heavy imports happen inside ``run``.
Exit status: :mod:`tools.cli.exit_codes`."""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from typing import Any

from pydantic import ValidationError

from shared.errors import StartupError
from shared.settings import settings_error_message

from . import exit_codes
from .help_text import HelpFormatter, description_of

#: sub-command -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "router": ("tools.cli.router", "run a Zenoh router (the embedded default for local stacks)"),
    "run": ("tools.cli.run", "run a service by name (recorder, lbl_nav, ...)"),
    "play": ("tools.cli.play", "play a scenario YAML or replay an MCAP recording onto Zenoh"),
    "record": ("tools.cli.record", "record Zenoh streams to MCAP"),
    "info": ("tools.cli.info", "what a recording holds (like ros2 bag info); --recover finalises a killed one"),
    "topics": ("tools.cli.topics", "list the live keys with their message type and rate"),
    "echo": ("tools.cli.echo", "print decoded messages on a key expression"),
    "hz": ("tools.cli.hz", "message rate on a key expression: mean, min/max/std of the intervals"),
    "status": ("tools.cli.status", "query every service's status"),
    "scenarios": ("tools.cli.scenarios", "list, show and validate scenario files"),
    "mc": ("tools.cli.mc", "Monte-Carlo runs of a scenario in-process, metrics to JSON"),
    "up": ("tools.cli.up", "run the compose.yaml stack as local processes"),
    "report": ("tools.cli.report", "evaluation report of a recording: HTML with plots + metrics JSON"),
    "foxglove": ("tools.cli.foxglove", "live bridge: Zenoh streams to the Foxglove app over WebSocket"),
    "pki": ("tools.cli.pki", "certificates for the secure stack (mutual TLS, one identity per role)"),
    "completion": ("tools.cli.completion", "print a shell completion script (bash, zsh)"),
}

LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL")
LOG_LEVEL_ENV = "FIXSTREAM_LOG_LEVEL"


class _Version(argparse.Action):
    """``--version``: the installed fixstream, its Zenoh and Python (read from the package metadata, no import)."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, *_: Any) -> None:
        print(version_text())
        parser.exit(exit_codes.OK)


def version_text() -> str:
    from importlib import metadata

    def of(dist: str) -> str:
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return "not installed"

    py = ".".join(map(str, sys.version_info[:3]))
    return f"fixstream {of('fixstream')} (eclipse-zenoh {of('eclipse-zenoh')}, Python {py})"


def _log_level(text: str) -> str:
    level = text.strip().upper()
    if level not in LOG_LEVELS:
        raise argparse.ArgumentTypeError(f"invalid log level {text!r} (choose from {', '.join(LOG_LEVELS)})")
    return level


def _add_log_level(parser: argparse.ArgumentParser, default: Any) -> None:
    parser.add_argument(
        "--log-level",
        type=_log_level,
        choices=LOG_LEVELS,
        default=default,
        metavar="{" + ",".join(LOG_LEVELS) + "}",
        help=f"log messages of this level and above, to stderr; default: ${LOG_LEVEL_ENV}, else INFO",
    )


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The full parser; only ``command``'s module is imported (all of them when None)."""
    parser = argparse.ArgumentParser(
        prog="fixstream",
        description="fixstream navigation and tracking stack",
        epilog=exit_codes.EPILOG,
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--version", action=_Version, help="print the version and exit")
    _add_log_level(parser, "INFO")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (module_name, help_text) in COMMANDS.items():
        if command is not None and name != command:
            sub.add_parser(name, help=help_text)
            continue
        module = importlib.import_module(module_name)
        p = sub.add_parser(
            name, help=help_text, description=description_of(module.__doc__, help_text), formatter_class=HelpFormatter
        )
        module.add_arguments(p)
        _add_log_level(p, argparse.SUPPRESS)  # also after the command: fixstream echo --log-level DEBUG
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in argv if a in COMMANDS), None)
    parser = build_parser(command)
    env_level = os.environ.get(LOG_LEVEL_ENV)
    if env_level:
        try:
            parser.set_defaults(log_level=_log_level(env_level))
        except argparse.ArgumentTypeError as exc:
            parser.error(f"${LOG_LEVEL_ENV}: {exc}")
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=getattr(logging, args.log_level),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        return exit_codes.INTERRUPTED
    except BrokenPipeError:  # the reader went away (fixstream echo | head): not an error of ours
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # so that the interpreter's final flush does not fail again
        return exit_codes.OK
    except StartupError as exc:
        print(f"fixstream {args.command}: {exc}", file=sys.stderr)
        return exit_codes.USAGE
    except ValidationError as exc:  # settings built outside ServiceSettings.load (e.g. ZenohSettings)
        print(f"fixstream {args.command}: {settings_error_message(exc)}", file=sys.stderr)
        return exit_codes.USAGE


if __name__ == "__main__":
    raise SystemExit(main())
