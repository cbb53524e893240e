"""``fixstream run NAME``: run the service ``services/NAME`` (configured from the environment)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", help="service folder name under services/, e.g. recorder, lbl_nav")


def run(args: argparse.Namespace) -> int:
    from ..registry import load_service

    service = load_service(args.name)
    service.install_signal_handlers()
    return service.run()
