"""Lossless publishing for the player and the replay: one reliable, blocking publisher per key."""

from __future__ import annotations

import contextlib
from collections import Counter

import zenoh

from schemas import Message
from shared import codec
from shared.recovery import Publisher, Recovery
from shared.settings import ZenohSettings


class _Slot:
    """A key's publisher, the encoding it last sent (string and Zenoh object) and how many puts it made."""

    __slots__ = ("count", "encoding", "pub", "zenoh_encoding")

    def __init__(self, pub: Publisher, encoding: str) -> None:
        self.pub = pub
        self.encoding = encoding
        self.zenoh_encoding = codec.zenoh_encoding(encoding)
        self.count = 0


class Publishers:
    """Declares a publisher per key on first use (``CongestionControl.BLOCK``, ``Reliability.RELIABLE``),
    so that nothing is dropped when the player runs as fast as possible; counts what was put per key. A key that
    ``recovery`` (None: the one :class:`ZenohSettings` of the environment gives) covers gets a publisher with a cache
    that subscribers recover lost samples from (shared/recovery.py)."""

    def __init__(self, session: zenoh.Session, recovery: Recovery | None = None) -> None:
        self.session = session
        self.recovery = recovery or Recovery.of(ZenohSettings())
        self._slots: dict[str, _Slot] = {}

    @property
    def counts(self) -> Counter[str]:
        """Messages put per key."""
        return Counter({key: slot.count for key, slot in self._slots.items() if slot.count})

    def put_bytes(self, key: str, payload: bytes, encoding: str) -> None:
        slot = self._slots.get(key)
        if slot is None:
            pub = self.recovery.declare_publisher(
                self.session,
                key,
                congestion_control=zenoh.CongestionControl.BLOCK,
                reliability=zenoh.Reliability.RELIABLE,
            )
            slot = self._slots[key] = _Slot(pub, encoding)
        elif slot.encoding is not encoding and slot.encoding != encoding:
            slot.encoding, slot.zenoh_encoding = encoding, codec.zenoh_encoding(encoding)
        slot.pub.put(payload, encoding=slot.zenoh_encoding)
        slot.count += 1

    def put(self, key: str, msg: Message) -> None:
        self.put_bytes(key, codec.encode(msg), codec.encoding_of(type(msg)))

    def put_stamped(self, key: str, msg: Message, source: str, seq: int) -> None:
        """``put`` of ``msg`` with ``header.source`` and ``header.seq`` replaced (the same bytes, no copy built)."""
        self.put_bytes(key, codec.encode_stamped(msg, source, seq), codec.encoding_of(type(msg)))

    def close(self) -> None:
        """Undeclare every publisher; ``counts`` still says what was put (the replay reports it after closing)."""
        for slot in self._slots.values():
            with contextlib.suppress(Exception):  # already gone with the session
                slot.pub.undeclare()
