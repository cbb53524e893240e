"""Recorder configuration from ``FIXSTREAM_RECORDER_*`` environment variables (and the optional config file).

=====================================  ==============================================================
``FIXSTREAM_RECORDER_OUT_DIR``          directory the MCAP files go to (created if missing)
``FIXSTREAM_RECORDER_KEY_EXPR``         Zenoh key expression to record, default ``fixstream/**``
``FIXSTREAM_RECORDER_COMPRESSION``      chunk compression: ``zstd`` (default), ``lz4`` or ``none``
``FIXSTREAM_RECORDER_CHUNK_SIZE_BYTES`` uncompressed bytes after which a chunk is closed and written
``FIXSTREAM_RECORDER_CHUNK_FLUSH_S``    longest wall time (s) a message waits in an open chunk
``FIXSTREAM_RECORDER_ROTATE_SIZE_MB``   start a new file once this many MB are written (0: never)
``FIXSTREAM_RECORDER_ROTATE_DURATION_S`` start a new file after this many seconds (0: never)
``FIXSTREAM_RECORDER_FILE_PREFIX``      file name prefix: ``<prefix>_<UTC>_<nnn>.mcap``
``FIXSTREAM_RECORDER_INSTANCE``         instance name (last chunk of the recorder's keys)
``FIXSTREAM_RECORDER_QUEUE_SIZE``       samples Zenoh holds for the recorder before it holds its sender (4096)
``FIXSTREAM_RECORDER_FOXGLOVE``         also write Foxglove scene and map channels (default false)
``FIXSTREAM_RECORDER_SCENARIOS_DIR``    the only directory a start marker's scenario name is looked up in
``FIXSTREAM_RECORDER_DIAG_INTERVAL_S``  the recorder's own diagnostics: one per reason per interval (1 s)
``FIXSTREAM_RECORDER_FILES_LIST``       a file to write the paths of this run's MCAP files to, one a line, at exit
=====================================  ==============================================================

The Zenoh connection comes from ``FIXSTREAM_ZENOH_*`` (:class:`shared.settings.ZenohSettings`).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

import zenoh
from pydantic import Field, field_validator
from pydantic_settings import SettingsConfigDict

from shared.settings import ServiceSettings

_PREFIX = re.compile(r"^[A-Za-z0-9_\-][A-Za-z0-9_.\-]*$")


class RecorderSettings(ServiceSettings):
    """What to record, where, and how the files are chunked and rotated."""

    model_config = SettingsConfigDict(env_prefix="FIXSTREAM_RECORDER_", extra="ignore")

    out_dir: Path = Field(default=Path("recordings"), description="directory of the MCAP files")
    key_expr: str = Field(default="fixstream/**", description="Zenoh key expression to record")
    compression: Literal["zstd", "lz4", "none"] = Field(default="zstd", description="chunk compression")
    chunk_size_bytes: int = Field(
        default=1 << 20, ge=256, description="uncompressed chunk size, bytes, after which the chunk is written"
    )
    chunk_flush_s: float = Field(
        default=1.0,
        gt=0.0,
        description="max wall time, s, a message waits in an open chunk; bounds what a SIGKILL can lose",
    )
    rotate_size_mb: float = Field(default=1024.0, ge=0.0, description="rotate after this many MB (1e6 bytes); 0: off")
    rotate_duration_s: float = Field(default=0.0, ge=0.0, description="rotate after this many seconds; 0: off")
    file_prefix: str = Field(default="fixstream", max_length=64, description="file name prefix, no path parts")
    foxglove: bool = Field(
        default=False,
        description="also write /foxglove/scene/<key> (foxglove.SceneUpdate) and /foxglove/location/<key> "
        "(foxglove.LocationFix[es]) channels converted from fixes, tracks and truth (shared/foxglove)",
    )
    scenarios_dir: Path | None = Field(
        default=None,
        description="the only directory a start marker's scenario name is looked up in (a plain name, never a path):"
        " its YAML and maps are attached, its frames and origin feed the Foxglove channels"
        " (default $FIXSTREAM_SCENARIOS_DIR or scenarios)",
    )
    queue_size: int = Field(
        default=4096,
        ge=16,
        le=1 << 20,
        description="samples held for the recorder (its inbox) before it holds the senders back; with the open chunk"
        " this is all a SIGKILL can lose",
    )
    enqueue_block_s: float = Field(
        default=30.0,
        ge=0.0,
        le=50.0,
        description="how long a full inbox holds the senders back (blocking publishers wait) before samples are dropped"
        " and counted (queue_full): a recorder behind for a while slows the stack rather than lose data, s",
    )
    diag_interval_s: float = Field(
        default=1.0,
        gt=0.0,
        le=3600.0,
        description="the recorder's own diagnostics (rejections, seq gaps) are aggregated: one per reason per interval"
        " (the payloads themselves are recorded on fixstream/rejected/<key>), s",
    )
    stop_drain_s: float = Field(
        default=5.0,
        ge=0.0,
        le=50.0,
        description="after SIGTERM, what still arrives (samples held back in Zenoh by a full inbox, the estimators'"
        " last outputs) is recorded until nothing has come for stop_quiet_s, at most this long (within compose's"
        " and fixstream up's 10 s before SIGKILL), s",
    )
    stop_quiet_s: float = Field(default=0.3, ge=0.0, le=10.0, description="the quiet that ends stop_drain_s early, s")
    status_timeout_s: float = Field(
        default=2.0, gt=0.0, le=60.0, description="how long a start marker's query of the services' status waits, s"
    )
    files_list: Path | None = Field(
        default=None,
        description="at exit, write the path of every MCAP file this recorder finalised to this file, one a line"
        " (fixstream up reports exactly its own recorder's files)",
    )
    max_attachment_bytes: int = Field(
        default=4 << 20, ge=0, description="largest scenario file or map attached to the recording, bytes"
    )

    @field_validator("file_prefix")
    @classmethod
    def _plain_name(cls, value: str) -> str:
        if "/" in value or "\\" in value or ".." in value or not _PREFIX.match(value):
            raise ValueError(
                f"file_prefix {value!r} must be a plain name: letters, digits, '_', '-', '.'; "
                "no path separators, no '..', not starting with '.'"
            )
        return value

    @field_validator("key_expr")
    @classmethod
    def _valid_key_expr(cls, value: str) -> str:
        try:
            zenoh.KeyExpr(value)
        except Exception as exc:  # zenoh raises its own error type
            raise ValueError(f"invalid Zenoh key expression {value!r}: {exc}") from None
        return value

    @property
    def rotate_size_bytes(self) -> int:
        """Rotation size in bytes (0: off)."""
        return int(self.rotate_size_mb * 1_000_000)
