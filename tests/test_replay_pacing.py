"""What paces a replay (services/player/replay.py), checked on the stamps it asks its pacer to wait for, not on a
clock: a player's start marker restarts the data clock, a start marker from anyone else does not (it once did, and
2,000 of them in a hostile file slowed a replay to ~500 s), and a gap in the log times longer than ``max_gap_s`` is
paced as ``max_gap_s`` and counted (one record stamped years ahead once held a replay at ``--rate 1`` for years).
The replay publishes on a real Zenoh session (peer mode, nothing listening): only the pacer is replaced.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar

import pytest
from mcap.writer import Writer
from samples import EXAMPLES

from schemas import Header, Message, ScenarioMarker
from services.player import replay as replay_module
from shared.session import open_session
from shared.settings import ZenohSettings

S = 1_000_000_000


class FakePacer:
    """Records the stamps it is asked to wait for, per instance (a new instance: the pacing restarted)."""

    made: ClassVar[list[FakePacer]] = []

    def __init__(self, rate: float, stop: Any = None) -> None:
        self.waits: list[int] = []
        FakePacer.made.append(self)

    def wait(self, stamp_ns: int) -> bool:
        self.waits.append(stamp_ns)
        return True


@pytest.fixture()
def pacers(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[FakePacer]]:
    FakePacer.made = []
    monkeypatch.setattr(replay_module, "Pacer", FakePacer)
    monkeypatch.setattr(replay_module, "START_MARKER_GAP_S", 0.0)
    yield FakePacer.made


@pytest.fixture(scope="module")
def session() -> Iterator[Any]:
    s = open_session(ZenohSettings(mode="peer", connect=[], listen=[]))
    yield s
    s.close()


def marker(source: str, event: str = "start") -> ScenarioMarker:
    return ScenarioMarker(
        header=Header(stamp_ns=0, frame_id="local_enu", source=source, seq=0), event=event, scenario="rec", seed=0
    )


def depth(seq: int) -> Message:
    return EXAMPLES["Depth"].model_copy(
        update={"header": Header(stamp_ns=seq * S, frame_id="local_enu", source="player/default", seq=seq)}
    )


def write(path: Path, records: list[tuple[str, Message, int]], chunk_size: int = 1 << 20) -> None:
    with path.open("wb") as f:
        w = Writer(f, chunk_size=chunk_size)
        w.start(profile="", library="test")
        channels: dict[str, int] = {}
        for key, msg, log_time in records:
            if key not in channels:
                schema = w.register_schema(name=f"fixstream.{type(msg).__name__}", encoding="jsonschema", data=b"{}")
                channels[key] = w.register_channel(topic=key, message_encoding="json", schema_id=schema)
            w.add_message(channels[key], log_time=log_time, data=msg.model_dump_json().encode(), publish_time=log_time)
        w.finish()


MARKERS, DEPTH = "fixstream/scenario/rec", "fixstream/sensor/p/depth/d0"


def test_only_a_players_start_marker_restarts_the_pacing(session: Any, pacers: list[FakePacer], tmp_path: Path) -> None:
    path = tmp_path / "rec.mcap"
    records = [(MARKERS, marker("player/default"), 0)] + [(DEPTH, depth(i), i * S) for i in range(1, 4)]
    records += [(MARKERS, marker("fuzz/x"), 0)] + [(DEPTH, depth(i), i * S) for i in range(4, 6)]
    records += [(MARKERS, marker("player/default", "end"), 5 * S), (MARKERS, marker("player/other"), 0)]
    records += [(DEPTH, depth(i), i * S) for i in range(1, 3)]
    write(path, records)
    result = replay_module.replay(session, path, rate=1.0, select=lambda key: True)
    assert result.total == len(records) and result.gaps_shortened == 0
    assert len(pacers) == 2  # the file's first run, and player/other's start: not fuzz/x's
    assert pacers[0].waits == [0, S, 2 * S, 3 * S, 3 * S, 4 * S, 5 * S, 5 * S]  # the foreign marker keeps the clock
    assert pacers[1].waits == [0, S, 2 * S]


def test_a_gap_beyond_max_gap_is_paced_as_max_gap_and_counted(
    session: Any, pacers: list[FakePacer], tmp_path: Path
) -> None:
    path = tmp_path / "rec.mcap"
    ahead = 2**62  # a valid stamp, about 146 years of data time
    records = [(DEPTH, depth(1), S), (DEPTH, depth(2), 2 * S), (DEPTH, depth(3), ahead), (DEPTH, depth(4), ahead + S)]
    records += [(DEPTH, depth(5), 3 * S)]  # back in time: waits for nothing new
    write(path, records)
    result = replay_module.replay(session, path, rate=1.0, select=lambda key: True, max_gap_s=60.0)
    assert result.total == 5 and result.gaps_shortened == 1
    (pacer,) = pacers
    assert pacer.waits == [S, 2 * S, 62 * S, 63 * S, 63 * S]
    # gaps within the bound are paced as they are: the same file with a bound above its gap
    pacers.clear()
    again = replay_module.replay(session, path, rate=1.0, select=lambda key: True, max_gap_s=ahead / 1e9)
    assert again.gaps_shortened == 0 and pacers[0].waits == [S, 2 * S, ahead, ahead + S, ahead + S]


def test_a_file_cut_short_replays_its_complete_chunks_and_says_what_it_left(
    session: Any, pacers: list[FakePacer], tmp_path: Path
) -> None:
    """A truncated recording (a crashed recorder, or one still being written) used to replay without a word."""
    path = tmp_path / "rec.mcap"
    write(path, [(DEPTH, depth(i), i * S) for i in range(1, 201)], chunk_size=2_000)
    whole = replay_module.replay(session, path, rate=0.0, select=lambda key: True)
    assert whole.total == 200 and whole.tail_bytes == 0
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    part = replay_module.replay(session, cut, rate=0.0, select=lambda key: True)
    assert 0 < part.total < 200 and part.completed
    assert 0 < part.tail_bytes < len(data) * 2 // 3  # the incomplete record's bytes, not read


def test_all_means_every_fixstream_key_and_keys_can_still_name_others() -> None:
    """--all once replayed a hostile file's record on other/app/cmd too (docs: every fixstream key)."""
    from services.player.selection import KeySelection

    everything = KeySelection.from_options(everything=True)
    assert everything("fixstream/fix/lbl/p1") and everything("fixstream/rejected/fixstream/sensor/p/depth/d0")
    assert not everything("other/app/cmd") and not everything("@/admin/x") and not everything("/foxglove/scene/x")
    assert KeySelection.from_options(["other/**"])("other/app/cmd")  # named: replayed


def test_a_record_on_a_wildcard_key_is_skipped_and_counted(
    session: Any, pacers: list[FakePacer], tmp_path: Path
) -> None:
    """A recorder subscribed to fixstream/** records a put on fixstream/sensor/** as it came; replayed, that put
    reached every sensor input of every service. No publisher of ours puts on a wildcard: skipped, counted."""
    path = tmp_path / "rec.mcap"
    write(path, [(DEPTH, depth(1), S), ("fixstream/sensor/**", depth(2), 2 * S), (DEPTH, depth(3), 3 * S)])
    result = replay_module.replay(session, path, rate=0.0, select=lambda key: True)
    assert result.published == {DEPTH: 2} and result.skipped == {"wildcard_key": 1}
