"""``fixstream record``: record Zenoh streams to MCAP in the foreground (the recorder service, CLI-configured).

Arguments override the ``FIXSTREAM_RECORDER_*`` environment; Zenoh arguments override ``FIXSTREAM_ZENOH_*``.
Stop with Ctrl-C or SIGTERM: the current file is finalised. Files are named
``<out-dir>/<prefix>_<UTC yyyymmddThhmmssZ>_<nnn>.mcap``.
"""

from __future__ import annotations

import argparse
import sys

from .common import add_zenoh_arguments, key_chunk

#: CLI option -> RecorderSettings field
_FIELDS = (
    "key_expr",
    "out_dir",
    "compression",
    "chunk_size_bytes",
    "chunk_flush_s",
    "rotate_size_mb",
    "rotate_duration_s",
    "file_prefix",
    "instance",
    "queue_size",
    "scenarios_dir",
    "diag_interval_s",
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--key-expr", help="key expression to record (default fixstream/**)")
    parser.add_argument("--out-dir", help="directory of the MCAP files (default ./recordings)")
    parser.add_argument("--compression", choices=["zstd", "lz4", "none"], help="chunk compression (default zstd)")
    parser.add_argument("--chunk-size-bytes", type=int, help="uncompressed chunk size, bytes (default 1 MiB)")
    parser.add_argument(
        "--chunk-flush-s",
        type=float,
        help="max seconds a message waits in an open chunk: with the FIFO, what a SIGKILL can lose (default 1.0)",
    )
    parser.add_argument("--rotate-size-mb", type=float, help="new file after this many MB; 0: off (default 1024)")
    parser.add_argument("--rotate-duration-s", type=float, help="new file after this many seconds; 0: off (default)")
    parser.add_argument("--file-prefix", help="file name prefix (default fixstream)")
    parser.add_argument(
        "--instance", type=key_chunk, help="instance name for the status/diag/alive keys (default 'default')"
    )
    parser.add_argument("--queue-size", type=int, help="samples Zenoh holds for the recorder (a FIFO; default 4096)")
    parser.add_argument("--scenarios-dir", help="the only directory start markers' scenario names are looked up in")
    parser.add_argument(
        "--diag-interval-s", type=float, help="one diagnostic per reason per this many seconds (default 1.0)"
    )
    add_zenoh_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from pydantic import ValidationError

    from services.recorder.service import RecorderService
    from services.recorder.settings import RecorderSettings
    from shared.settings import settings_error_message

    from . import exit_codes
    from .common import ensure_dir, zenoh_settings_from

    overrides = {name: getattr(args, name) for name in _FIELDS if getattr(args, name, None) is not None}
    try:
        settings = RecorderSettings.load(**overrides)
    except ValidationError as exc:
        print(f"fixstream record: {settings_error_message(exc)}", file=sys.stderr)
        return exit_codes.USAGE
    assert isinstance(settings, RecorderSettings)
    ensure_dir(Path(settings.out_dir))  # before connecting: a bad --out-dir is one line and exit code 2
    service = RecorderService(settings, zenoh_settings_from(args))
    service.install_signal_handlers()
    return service.run()
