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


#: the longest time any option takes, s (about 31 years): beyond it a wait overflows the OS's timeouts
#: (``threading.TIMEOUT_MAX``, about 9.2e9 s here) and a deadline's float arithmetic loses its seconds
MAX_SECONDS = 1e9
#: the most runs, intervals or messages a count option takes: beyond it a count only exhausts memory
MAX_COUNT = 10_000_000
#: the slowest replay rate (times real time) other than 0: a million times slower than real time
MIN_RATE = 1e-6
MAX_RATE = 1e9


def _integer(text: str, lowest: int, highest: int) -> int:
    """An integer ``lowest``..``highest`` of an option; else a usage error (exit code 2), not numpy's traceback or a
    MemoryError later."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if not lowest <= value <= highest:
        raise argparse.ArgumentTypeError(f"{value}: must be between {lowest} and {highest:,}")
    return value


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def non_negative_int(text: str) -> int:
    """argparse ``type=``: an integer 0..``MAX_COUNT`` (a run index, a count)."""
    return _integer(text, 0, MAX_COUNT)


def positive_int(text: str) -> int:
    """argparse ``type=``: an integer 1..``MAX_COUNT`` (a count)."""
    return _integer(text, 1, MAX_COUNT)


def seed(text: str) -> int:
    """argparse ``type=``: a seed, 0 .. 2**63 - 1 (what a scenario's ``seed`` takes)."""
    return _integer(text, 0, 2**63 - 1)


def seconds(text: str) -> float:
    """argparse ``type=``: a duration, a finite number of seconds 0..``MAX_SECONDS``; NaN, infinity and overflowing
    values are usage errors (``nan`` used to play as fast as possible, ``--duration nan`` never ended, and
    ``--timeout 1e20`` overflowed the OS's wait)."""
    value = _float(text)
    if not 0.0 <= value <= MAX_SECONDS:  # NaN too
        raise argparse.ArgumentTypeError(f"{text}: must be a number of seconds from 0 to {MAX_SECONDS:g}")
    return value


def positive_seconds(text: str) -> float:
    """argparse ``type=``: as :func:`seconds`, but > 0 (an interval between updates)."""
    value = seconds(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"{text}: must be > 0 s")
    return value


def rate(text: str) -> float:
    """argparse ``type=``: a replay rate, times real time: 0 (as fast as possible) or ``MIN_RATE``..``MAX_RATE``."""
    value = _float(text)
    if not (value == 0.0 or MIN_RATE <= value <= MAX_RATE):  # NaN too
        raise argparse.ArgumentTypeError(f"{text}: must be 0 (as fast as possible) or {MIN_RATE:g} to {MAX_RATE:g}")
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
