"""Which recorded keys a replay puts back on Zenoh (``fixstream play FILE.mcap --keys/--exclude/--all``).

A recording holds what the player fed in (sensors, truth, scenario markers, the AUV group's uplink) and what the
services answered (fixes, tracks, diagnostics, the coordinator's decisions). Replayed into a running stack, the
inputs make the services compute their answers again; republishing the recorded answers as well would put two
sets of fixes side by side on the same keys. So by default a replay republishes only :data:`PLAYER_KEYS`, the keys
a player publishes (the same set the secure router lets the ``player`` identity write,
``tools/stack/router-secure.json5``); ``--all`` replays every fixstream key, ``--keys`` names the key expressions to
replay instead, ``--exclude`` removes key expressions from either.

A payload the recorder kept as rejected (channel ``fixstream/rejected/<key>``) is selected by its original key,
where the replay puts it back.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

#: the keys a player publishes: what a replay republishes by default
PLAYER_KEYS: tuple[str, ...] = (
    "fixstream/sensor/**",
    "fixstream/truth/**",
    "fixstream/scenario/**",
    "fixstream/group/*/uplink/**",
)
#: what ``--all`` replays: every fixstream key
ALL_KEYS: tuple[str, ...] = ("fixstream/**",)
#: channel prefix of payloads the recorder kept as rejected (replayed on the key after it)
REJECTED_PREFIX = "fixstream/rejected/"
#: schema-name prefixes of the channels a replay publishes: the models, the recorder's rejected-payload envelope
FIXSTREAM_SCHEMAS = ("fixstream.", "fixstream_raw.")


def original_key(topic: str) -> str:
    """The Zenoh key a recorded channel's messages go back on."""
    return topic.removeprefix(REJECTED_PREFIX)


@dataclass
class KeySelection:
    """``include`` (None: every key) minus ``exclude``, as Zenoh key expressions; called with a channel topic."""

    include: tuple[str, ...] | None = PLAYER_KEYS
    exclude: tuple[str, ...] = ()
    _cache: dict[str, bool] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self._include = None if self.include is None else [zenoh.KeyExpr(k) for k in self.include]
        self._exclude = [zenoh.KeyExpr(k) for k in self.exclude]

    @classmethod
    def from_options(
        cls, keys: Iterable[str] = (), exclude: Iterable[str] = (), everything: bool = False
    ) -> KeySelection:
        """``--keys`` (replaces the default), ``--all`` (every fixstream key, ``fixstream/**``: a key outside it, which
        a hostile file may hold, is replayed only when ``--keys`` names it) and ``--exclude`` (removed from either)."""
        named = tuple(keys)
        include = named if named else (ALL_KEYS if everything else PLAYER_KEYS)
        return cls(include, tuple(exclude))

    def __call__(self, topic: str) -> bool:
        found = self._cache.get(topic)
        if found is None:
            found = self._cache[topic] = self._selects(original_key(topic))
        return found

    def _selects(self, key: str) -> bool:
        try:
            k = zenoh.KeyExpr(key)
        except zenoh.ZError:
            return False  # not a Zenoh key (e.g. a Foxglove channel's /foxglove/... topic): nothing to replay on
        if self._include is not None and not any(i.includes(k) for i in self._include):
            return False
        return not any(e.includes(k) for e in self._exclude)

    def describe(self) -> str:
        what = "every key" if self.include is None else " ".join(self.include)
        return what + (f" except {' '.join(self.exclude)}" if self.exclude else "")


def selected_total(path: str | Path, select: KeySelection) -> int | None:
    """How many records of a finalised recording the replay will publish (from its summary's statistics: no data is
    read); None when the file has no summary (a recording cut short) or no statistics."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:  # a truncated or foreign file: the replay itself reports what is wrong with it
        return None
    if summary is None or summary.statistics is None:
        return None
    total = 0
    for channel_id, count in summary.statistics.channel_message_counts.items():
        channel = summary.channels.get(channel_id)
        if channel is None:
            continue
        schema = summary.schemas.get(channel.schema_id)
        # fixstream's own schemas (and the recorder's envelope of rejected payloads); not Foxglove's
        if schema is not None and schema.name.startswith(FIXSTREAM_SCHEMAS) and select(channel.topic):
            total += count
    return total
