"""The one wire format: msgpack of the pydantic model, schema name and version in the Zenoh encoding.

The encoding string is ``application/msgpack;fixstream.<Model>/<version>``. Decoding never trusts the
payload: the schema must be known, the msgpack must be complete with no trailing bytes, and the object
must validate strictly against the model. Every failure raises :class:`DecodeError` with a short reason
code (for diagnostics counters) and a human-readable detail.
"""

from __future__ import annotations

from typing import Any

import msgpack
import zenoh
from pydantic import ValidationError

from schemas import MODELS, Message

MEDIA_TYPE = "application/msgpack"
_PREFIX = MEDIA_TYPE + ";"


class DecodeError(ValueError):
    """A payload that cannot become a valid message. ``reason`` is a short code for counters."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


_ENCODING_OF: dict[type[Message], str] = {}


def encoding_of(model: type[Message]) -> str:
    """``application/msgpack;fixstream.<Model>/<version>`` (built once per model: hot publish paths)."""
    enc = _ENCODING_OF.get(model)
    if enc is None:
        enc = _ENCODING_OF[model] = _PREFIX + model.schema_id()
    return enc


_ZENOH_ENCODINGS: dict[str, zenoh.Encoding] = {}


def zenoh_encoding(encoding: str) -> zenoh.Encoding:
    """The ``zenoh.Encoding`` for an encoding string, built once per string (hot publish paths)."""
    enc = _ZENOH_ENCODINGS.get(encoding)
    if enc is None:
        enc = _ZENOH_ENCODINGS[encoding] = zenoh.Encoding(encoding)
    return enc


def encode(msg: Message) -> bytes:
    """msgpack bytes of ``msg`` (plain dicts, lists, str, int, float, bool, None).

    The model's serializer is called directly: the same dict as ``msg.model_dump(mode="python")`` without the
    wrapper's argument handling (hot publish paths)."""
    return msgpack.packb(msg.__pydantic_serializer__.to_python(msg), use_bin_type=True)


def encode_stamped(msg: Message, source: str, seq: int) -> bytes:
    """The bytes of ``encode(msg)`` with ``header.source`` and ``header.seq`` replaced, without building the
    stamped copy of the message (``model_copy`` plus a new ``Header``: more than the encoding itself). The caller
    vouches for ``source`` and ``seq`` (a publisher's own name and counter)."""
    data = msg.__pydantic_serializer__.to_python(msg)
    header = data["header"]
    header["source"] = source
    header["seq"] = seq
    return msgpack.packb(data, use_bin_type=True)


_MODEL_CACHE: dict[str, type[Message]] = {}


def model_for_encoding(encoding: str) -> type[Message]:
    """Resolve ``application/msgpack;fixstream.Name/1`` to the model class, or raise DecodeError."""
    cached = _MODEL_CACHE.get(encoding)
    if cached is not None:
        return cached
    model = _resolve(encoding)
    if len(_MODEL_CACHE) < 4096:  # encodings come from the network: bound what is remembered
        _MODEL_CACHE[encoding] = model
    return model


def _resolve(encoding: str) -> type[Message]:
    if not encoding.startswith(_PREFIX):
        raise DecodeError("bad_encoding", f"expected {MEDIA_TYPE};fixstream.<Model>/<v>, got {encoding!r}")
    schema = encoding[len(_PREFIX) :]
    name, _, version = schema.removeprefix("fixstream.").partition("/")
    model = MODELS.get(name)
    if model is None or not schema.startswith("fixstream."):
        raise DecodeError("unknown_schema", f"no model named {schema!r}")
    if version != str(model.schema_version):
        raise DecodeError("schema_version", f"{name} version {version!r}, this build speaks {model.schema_version}")
    return model


def unpack(payload: bytes) -> Any:
    try:
        return msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except msgpack.ExtraData as exc:
        raise DecodeError("trailing_bytes", f"{len(exc.extra)} bytes after the message") from None
    except (ValueError, msgpack.UnpackException, TypeError) as exc:
        raise DecodeError("bad_msgpack", f"{type(exc).__name__}: {exc}") from None


def validate(model: type[Message], obj: Any) -> Message:
    try:
        return model.__pydantic_validator__.validate_python(obj, strict=True)  # = model_validate, no wrapper
    except ValidationError as exc:
        errors = exc.errors(include_url=False)
        first = errors[0] if errors else {"loc": (), "msg": str(exc)}
        loc = ".".join(str(p) for p in first.get("loc", ())) or "<root>"
        reason = _reason_of(first)
        raise DecodeError(reason, f"{model.__name__}.{loc}: {first.get('msg')} ({len(errors)} error(s))") from None


def _reason_of(error: Any) -> str:
    kind = str(error.get("type", "invalid"))
    if kind == "finite_number":
        return "non_finite"
    if kind == "missing":
        return "missing_field"
    if kind == "extra_forbidden":
        return "extra_field"
    if kind.endswith("_type") or kind == "model_type":
        return "wrong_type"
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        return "out_of_bounds"
    return "invalid"


def decode(payload: bytes, encoding: str) -> Message:
    """Bytes and encoding string -> validated message, or DecodeError."""
    model = _MODEL_CACHE.get(encoding) or model_for_encoding(encoding)
    return validate(model, unpack(payload))


def decode_as(model: type[Message], payload: bytes) -> Message:
    return validate(model, unpack(payload))
