"""``fixstream run NAME``: run the service ``services/NAME`` (configured from the environment)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", help="service folder name under services/, e.g. recorder, lbl_nav")


def run(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from shared.errors import StartupError
    from shared.settings import settings_error_message

    from ..registry import load_service

    try:
        service = load_service(args.name)
    except ValidationError as exc:
        raise StartupError(f"cannot start {args.name}: {settings_error_message(exc)}") from None
    except (OSError, ValueError) as exc:  # a map that is not there, a configuration the core refuses, ...
        detail = " ".join(str(exc).split())
        raise StartupError(f"cannot start {args.name}: {type(exc).__name__}: {detail}") from None
    service.install_signal_handlers()
    return service.run()
