"""Arguments shared by the client commands: how to reach Zenoh."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from shared.errors import StartupError
from shared.settings import ZenohSettings

#: a command-line client waits less for its router than a service does (a user is waiting at the prompt)
CLIENT_CONNECT_TIMEOUT_S = 5.0


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("zenoh")
    g.add_argument(
        "--connect",
        action="append",
        help="endpoint to connect to (repeatable); default: $FIXSTREAM_ZENOH_CONNECT, else the running local stack"
        " (fixstream up), else tcp/127.0.0.1:7447",
    )
    g.add_argument(
        "--connect-timeout",
        type=connect_timeout,
        help="seconds to keep retrying the router before giving up (default: $FIXSTREAM_ZENOH_CONNECT_TIMEOUT_S or 5)",
    )
    g.add_argument("--listen", action="append", help="endpoint to listen on (repeatable)")
    g.add_argument("--mode", choices=["client", "peer", "router"], help="session mode; default from env")


def key_expr(text: str) -> str:
    """argparse ``type=``: a valid Zenoh key expression (an invalid one is a usage error, exit code 2)."""
    import zenoh

    try:
        return str(zenoh.KeyExpr(text))
    except zenoh.ZError:
        raise argparse.ArgumentTypeError(f"not a valid Zenoh key expression: {text!r}") from None


def connect_timeout(text: str) -> float:
    """argparse ``type=``: seconds, -1 (forever) or more (ZenohSettings' bound, which ``model_copy`` does not check)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of seconds: {text!r}") from None
    if not value >= -1.0:  # NaN too
        raise argparse.ArgumentTypeError(f"{text} s: must be >= 0, or -1 to retry forever")
    return value


def non_negative_int(text: str) -> int:
    """argparse ``type=``: an integer >= 0 (a seed, a run index); else a usage error (exit code 2), not numpy's
    traceback later."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value}: must be >= 0")
    return value


def positive_int(text: str) -> int:
    """argparse ``type=``: an integer >= 1 (a count)."""
    value = non_negative_int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value}: must be >= 1")
    return value


def non_negative_float(text: str) -> float:
    """argparse ``type=``: a finite number >= 0 (seconds, a rate); NaN and infinity are usage errors too (``nan``
    used to play as fast as possible, and ``--duration nan`` never ended)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"{text}: must be a finite number >= 0")
    return value


def key_chunk(text: str) -> str:
    """argparse ``type=``: one chunk of a key (an instance name): no '/', no wildcard, not empty."""
    from shared import keys

    if not keys.is_chunk(text):
        raise argparse.ArgumentTypeError(
            f"{text!r}: not a key chunk (letters, digits, '_', '-', '.'; no '/', '*', '$', '#', '?', '@')"
        )
    return text


def port_number(text: str) -> int:
    """argparse ``type=``: a TCP port, 0-65535 (a usage error otherwise, exit code 2)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"port {value} out of range (0-65535)")
    return value


def ensure_dir(path: Path) -> None:
    """Create the directory ``path`` (and its parents) if missing; :class:`StartupError` (one line, exit code 2) when
    it is not a directory or cannot be created."""
    if path.exists() and not path.is_dir():
        raise StartupError(f"{path}: exists and is not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StartupError(f"{path}: cannot create the directory: {exc.strerror or exc}") from None


def check_output_file(path: Path) -> None:
    """Before long work: :class:`StartupError` unless the file ``path`` can be written (its directory is created;
    a file created to try is removed again)."""
    if path.is_dir():
        raise StartupError(f"{path}: is a directory (give a file name)")
    ensure_dir(path.parent)
    existed = path.exists()
    try:
        with open(path, "a"):
            pass
    except OSError as exc:
        raise StartupError(f"{path}: cannot write: {exc.strerror or exc}") from None
    if not existed:
        os.unlink(path)


def zenoh_settings_from(args: argparse.Namespace) -> ZenohSettings:
    overrides: dict[str, object] = {}
    if getattr(args, "connect", None):
        overrides["connect"] = args.connect
    if getattr(args, "listen", None):
        overrides["listen"] = args.listen
    if getattr(args, "mode", None):
        overrides["mode"] = args.mode
    if getattr(args, "connect_timeout", None) is not None:
        overrides["connect_timeout_s"] = args.connect_timeout
    base = ZenohSettings()
    if "connect_timeout_s" not in overrides and "connect_timeout_s" not in base.model_fields_set:
        overrides["connect_timeout_s"] = CLIENT_CONNECT_TIMEOUT_S
    return base.model_copy(update=overrides)
