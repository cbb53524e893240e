"""The unit of a scenario's stream: one message to publish at one stamp on one key (the player's simulators make
them; the Monte-Carlo runner and the metrics read them)."""

from __future__ import annotations

from typing import NamedTuple

from schemas import Message


class Event(NamedTuple):
    """One message to publish: stamp on the simulated clock (ns), key expression and the message."""

    stamp_ns: int
    key: str
    msg: Message
