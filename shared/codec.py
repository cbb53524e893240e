"""The one wire format: msgpack of the pydantic model, schema name and version in the Zenoh encoding.

The encoding string is ``application/msgpack;fixstream.<Model>/<version>``. Decoding never trusts the
payload: the schema must be known, the msgpack must be complete with no trailing bytes, and the object
must validate strictly against the model. Every failure raises :class:`DecodeError` with a short reason
code (for diagnostics counters) and a human-readable detail.
"""

from __future__ import annotations

import threading
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


_ZENOH_ENCODING_OF: dict[type[Message], zenoh.Encoding] = {}


def zenoh_encoding_of(model: type[Message]) -> zenoh.Encoding:
    """``zenoh_encoding(encoding_of(model))`` in one lookup (every publish)."""
    enc = _ZENOH_ENCODING_OF.get(model)
    if enc is None:
        enc = _ZENOH_ENCODING_OF[model] = zenoh_encoding(encoding_of(model))
    return enc


class _Packers(threading.local):
    """One ``msgpack.Packer`` per thread: ``Packer(use_bin_type=True).pack`` gives the bytes of
    ``msgpack.packb(obj, use_bin_type=True)`` without building a packer and parsing its options on every call (hot
    publish paths); a packer keeps a buffer, so no two threads share one."""

    def __init__(self) -> None:
        self.pack = msgpack.Packer(use_bin_type=True).pack


_PACKERS = _Packers()


def encode(msg: Message) -> bytes:
    """msgpack bytes of ``msg`` (plain dicts, lists, str, int, float, bool, None).

    The model's serializer is called directly: the same dict as ``msg.model_dump(mode="python")`` without the
    wrapper's argument handling (hot publish paths)."""
    return _PACKERS.pack(msg.__pydantic_serializer__.to_python(msg))


def encode_stamped(msg: Message, source: str, seq: int) -> bytes:
    """The bytes of ``encode(msg)`` with ``header.source`` and ``header.seq`` replaced, without building the
    stamped copy of the message (``model_copy`` plus a new ``Header``: more than the encoding itself). The caller
    vouches for ``source`` and ``seq`` (a publisher's own name and counter)."""
    data = msg.__pydantic_serializer__.to_python(msg)
    header = data["header"]
    header["source"] = source
    header["seq"] = seq
    return _PACKERS.pack(data)


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


#: largest payload decoded, bytes (a service's own ``max_payload_bytes`` refuses earlier, before its queue)
MAX_PAYLOAD_BYTES = 4 << 20
#: per-object limits handed to msgpack, so that no payload allocates beyond what its size allows: the largest
#: legitimate message (a scan of a few thousand plots, a marker naming thousands of keys) is far below each one.
#: Nesting is bounded by msgpack's own stack (1024 levels: ``StackError``, reported as ``bad_msgpack``).
MAX_STR_LEN = 1 << 16
MAX_BIN_LEN = 1 << 20
MAX_ARRAY_LEN = 1 << 17
MAX_MAP_LEN = 1 << 14


def unpack(payload: bytes) -> Any:
    """The msgpack object of a payload, within the size and per-object limits above (else DecodeError)."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise DecodeError("payload_too_large", f"{len(payload)} bytes > {MAX_PAYLOAD_BYTES}")
    try:
        return msgpack.unpackb(
            payload,
            raw=False,
            strict_map_key=True,
            max_str_len=MAX_STR_LEN,
            max_bin_len=MAX_BIN_LEN,
            max_array_len=MAX_ARRAY_LEN,
            max_map_len=MAX_MAP_LEN,
            max_ext_len=0,
        )
    except msgpack.ExtraData as exc:
        raise DecodeError("trailing_bytes", f"{len(exc.extra)} bytes after the message") from None
    except ValueError as exc:
        if "exceeds max_" in str(exc):
            raise DecodeError("too_large", str(exc)) from None
        raise DecodeError("bad_msgpack", f"{type(exc).__name__}: {exc}") from None
    except (msgpack.UnpackException, TypeError) as exc:
        raise DecodeError("bad_msgpack", f"{type(exc).__name__}: {exc}") from None


def header_of(obj: Any) -> tuple[str, int, int] | None:
    """``(header.source, header.seq, header.stamp_ns)`` of an unpacked message, or None if it has no well-formed
    header (the validation reports why). Used for per-publisher accounting and the input stamp range, before and
    whatever the message's validation."""
    header = obj.get("header") if type(obj) is dict else None
    if type(header) is not dict:
        return None
    source, seq, stamp = header.get("source", ""), header.get("seq", 0), header.get("stamp_ns")
    if type(source) is not str or type(seq) is not int or type(stamp) is not int:
        return None
    return source, seq, stamp


def peek_header(payload: bytes) -> tuple[str, int, int] | None:
    """:func:`header_of` the payload, or None if it does not unpack (within the limits)."""
    try:
        return header_of(unpack(payload))
    except DecodeError:
        return None


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
