"""Lossless publishing for the player and the replay: one reliable, blocking publisher per key."""

from __future__ import annotations

import contextlib
from collections import Counter

import zenoh

from schemas import Message
from shared import codec


class Publishers:
    """Declares a publisher per key on first use (``CongestionControl.BLOCK``, ``Reliability.RELIABLE``),
    so that nothing is dropped when the player runs as fast as possible; counts what was put per key."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self.counts: Counter[str] = Counter()
        self._pubs: dict[str, zenoh.Publisher] = {}

    def put_bytes(self, key: str, payload: bytes, encoding: str) -> None:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self.session.declare_publisher(
                key, congestion_control=zenoh.CongestionControl.BLOCK, reliability=zenoh.Reliability.RELIABLE
            )
            self._pubs[key] = pub
        pub.put(payload, encoding=codec.zenoh_encoding(encoding))
        self.counts[key] += 1

    def put(self, key: str, msg: Message) -> None:
        self.put_bytes(key, codec.encode(msg), codec.encoding_of(type(msg)))

    def put_stamped(self, key: str, msg: Message, source: str, seq: int) -> None:
        """``put`` of ``msg`` with ``header.source`` and ``header.seq`` replaced (the same bytes, no copy built)."""
        self.put_bytes(key, codec.encode_stamped(msg, source, seq), codec.encoding_of(type(msg)))

    def close(self) -> None:
        for pub in self._pubs.values():
            with contextlib.suppress(Exception):  # already gone with the session
                pub.undeclare()
        self._pubs.clear()
