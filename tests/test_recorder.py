"""The recorder end to end: a real router, a real recorder process, a real Zenoh client, real MCAP files."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections import Counter
from pathlib import Path

import msgpack
import pytest
from conftest import REPO, fixstream_cmd, wait_until
from mcap.reader import make_reader
from recorder_support import by_topic, examples, recorder, records_of, restamp
from samples import EXAMPLES
from test_player_zenoh import Collector

from schemas import Diagnostic, Header, Message, ScenarioMarker
from shared import codec, keys
from shared.mcap_io import (
    MAGIC,
    REJECTED_PREFIX,
    decode_record,
    decode_rejected,
    is_rejected,
    iter_records,
    recording_files,
)

pytestmark = pytest.mark.e2e


# ----- recording, both compressions, both launchers ---------------------------------------------------


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_records_every_message_exactly(router: str, tmp_path: Path, compression: str) -> None:
    """zstd through ``fixstream run recorder`` + env; lz4 through ``fixstream record`` whose arguments
    override an environment that names another directory, another compression and a dead endpoint."""
    rounds = 4
    decoy = tmp_path / "env_out"
    cli, env = None, {"FIXSTREAM_RECORDER_COMPRESSION": compression}
    if compression == "lz4":
        cli = ["--compression", "lz4", "--out-dir", str(tmp_path / "out"), "--connect", router]
        env = {
            "FIXSTREAM_RECORDER_COMPRESSION": "zstd",
            "FIXSTREAM_RECORDER_OUT_DIR": str(decoy),
            "FIXSTREAM_ZENOH_CONNECT": "tcp/127.0.0.1:9",
        }
    sent: dict[str, list[Message]] = {}
    with recorder(router, tmp_path, cli=cli, **env) as rec:
        for i in range(rounds):
            for name, example in examples().items():
                key = f"fixstream/test/{name.lower()}"
                msg = restamp(example, i, f"test/{name}")
                rec.send(key, msg)
                sent.setdefault(key, []).append(msg)
        total = sum(len(v) for v in sent.values())
        status = rec.wait_status(lambda s: s["written"] >= total)
        assert status["written"] == total
        assert (status["lost"], status["counters"]["rejected"]) == (0, 0)
        assert status["current_file"] is not None
        rec.terminate()

    files = recording_files(rec.out_dir)
    assert len(files) == 1 and Path(status["current_file"]) == files[0]
    assert not decoy.exists()
    records = records_of(files)
    got = by_topic(records)
    assert {k: len(v) for k, v in got.items()} == {k: len(v) for k, v in sent.items()}
    assert got == sent
    for r in records:
        assert (r.schema_encoding, r.message_encoding) == ("jsonschema", "json")
        assert r.schema_name == f"fixstream.{type(sent[r.topic][0]).__name__}"
        assert r.publish_time_ns == decode_record(r).header.stamp_ns
    with files[0].open("rb") as f:  # finalised: the official reader finds summary, statistics and footer
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == len(records)
    assert {c.compression for c in summary.chunk_indexes} == {compression}
    assert files[0].read_bytes().endswith(MAGIC)


def test_rotation_by_size_keeps_every_message_once(router: str, tmp_path: Path) -> None:
    env = {
        "FIXSTREAM_RECORDER_CHUNK_SIZE_BYTES": "2048",
        "FIXSTREAM_RECORDER_ROTATE_SIZE_MB": "0.006",
        "FIXSTREAM_RECORDER_KEY_EXPR": "fixstream/truth/**",
    }
    n = 300
    with recorder(router, tmp_path, **env) as rec:
        sent = [restamp(EXAMPLES["Truth"], i, "test/truth") for i in range(n)]
        for msg in sent:
            rec.send("fixstream/truth/auv1", msg)
        rec.wait_status(lambda s: s["written"] >= n)
        rec.terminate()
    files = recording_files(rec.out_dir)
    assert len(files) >= 3, files
    for path in files:
        assert path.read_bytes().endswith(MAGIC), f"{path} not finalised"
        assert path.stat().st_size < 6000 + 2048 + 4000  # limit + one chunk + summary and footer
    got = [decode_record(r) for r in records_of(files)]
    assert got == sent


def test_sigkill_leaves_a_readable_file(router: str, tmp_path: Path) -> None:
    env = {"FIXSTREAM_RECORDER_CHUNK_FLUSH_S": "0.3", "FIXSTREAM_RECORDER_KEY_EXPR": "fixstream/sensor/**"}
    key = "fixstream/sensor/auv1/depth/d0"
    first = [restamp(EXAMPLES["Depth"], i, "test/depth") for i in range(50)]
    with recorder(router, tmp_path, **env) as rec:
        for msg in first:
            rec.send(key, msg)
        status = rec.wait_status(lambda s: s["written"] >= len(first) and s["current_file"])
        path = Path(status["current_file"])
        # the chunk holding the first batch is closed after chunk_flush_s and reaches the file
        assert wait_until(lambda: sum(1 for _ in iter_records(path)) >= len(first), timeout=10)
        second = [restamp(EXAMPLES["Depth"], 50 + i, "test/depth") for i in range(20)]
        for msg in second:
            rec.send(key, msg)
        rec.proc.kill()
        assert rec.proc.wait(timeout=10) == -signal.SIGKILL
    data = path.read_bytes()
    assert not data.endswith(MAGIC)  # really not finalised
    got = [decode_record(r) for r in iter_records(path)]
    assert len(got) >= len(first)
    assert got == (first + second)[: len(got)]


def test_seq_gaps_and_resets_are_reported(router: str, tmp_path: Path) -> None:
    diags: list[Diagnostic] = []
    with recorder(router, tmp_path, instance="gaps") as rec:
        sub = rec.session.declare_subscriber(
            keys.diag("recorder", "gaps"),
            lambda s: diags.append(codec.decode(s.payload.to_bytes(), str(s.encoding))),  # type: ignore[arg-type]
        )
        key = "fixstream/sensor/auv1/depth/d1"
        for seq in (0, 1, 2, 5):
            rec.send(key, restamp(EXAMPLES["Depth"], seq, "test/gappy"))
        assert wait_until(lambda: any(d.reason == "seq_gap" for d in diags), timeout=10), rec.log()
        gap = next(d for d in diags if d.reason == "seq_gap")
        assert gap.key == key and "2 lost" in gap.detail and "test/gappy" in gap.detail
        status = rec.wait_status(lambda s: s["written"] >= 4)
        assert (status["lost"], status["seq_gaps"], status["seq_resets"]) == (2, 1, 0)
        rec.send(key, restamp(EXAMPLES["Depth"], 0, "test/gappy"))  # the publisher restarted
        assert wait_until(lambda: any(d.reason == "seq_reset" for d in diags), timeout=10)
        status = rec.wait_status(lambda s: s["seq_resets"] == 1)
        assert status["lost"] == 2 and status["counters"]["rejected"] == 0
        sub.undeclare()
        rec.terminate()
    topics = Counter(r.topic for r in records_of(recording_files(rec.out_dir)))
    assert topics[key] == 5  # gaps and resets are reported, the messages are still recorded
    assert topics[keys.diag("recorder", "gaps")] >= 2  # its own diagnostics are on fixstream/** too


def test_a_tail_no_seq_shows_is_counted_against_the_end_marker(router: str, tmp_path: Path) -> None:
    """A player's run on four keys, each cut differently: ``whole`` arrives whole, ``gap`` loses seq 2 in the
    middle (the seq check sees it when seq 3 comes), ``head`` its first two (its stream counts from 0 after the
    start marker), ``tail`` its last two (no later message shows them). Against the end marker's counts (5 each)
    the recorder counts the gap and the head as ``lost`` and the tail as ``lost_at_end``, one diagnostic naming
    the key. A second player whose start marker the recorder never saw is not judged (what it published before
    the recorder joined was not lost in transport)."""
    diags: list[Diagnostic] = []
    source, stranger = "player/tails", "player/joined-late"
    whole, gap, head, tail = (f"fixstream/sensor/auv1/depth/{k}" for k in ("whole", "gap", "head", "tail"))

    def marker(event: str, seq: int, src: str, published: dict[str, int]) -> ScenarioMarker:
        header = Header(stamp_ns=1_000_000 * (1 + seq), frame_id="scenario", source=src, seq=seq)
        return ScenarioMarker(header=header, event=event, scenario="tails", seed=1, published=published)

    with recorder(router, tmp_path, instance="tails") as rec:
        sub = rec.session.declare_subscriber(
            keys.diag("recorder", "tails"),
            lambda s: diags.append(codec.decode(s.payload.to_bytes(), str(s.encoding))),  # type: ignore[arg-type]
        )
        markers = "fixstream/scenario/tails"
        rec.send(markers, marker("start", 0, source, {}))
        for key, seqs in ((whole, range(5)), (gap, (0, 1, 3, 4)), (head, (2, 3, 4)), (tail, range(3))):
            for seq in seqs:
                rec.send(key, restamp(EXAMPLES["Depth"], seq, source))
        rec.send(markers, marker("end", 1, source, {whole: 5, gap: 5, head: 5, tail: 5, markers: 1}))
        rec.send(tail, restamp(EXAMPLES["Depth"], 7, stranger))
        rec.send(markers, marker("end", 0, stranger, {tail: 9}))
        status = rec.wait_status(lambda s: s["lost_at_end"] > 0)
        assert (status["lost"], status["lost_at_end"], status["seq_gaps"]) == (3, 2, 2)
        assert wait_until(lambda: any(d.reason == "lost_at_end" for d in diags), timeout=10), rec.log()
        end = next(d for d in diags if d.reason == "lost_at_end")
        assert end.key == tail and "2 on " + tail in end.detail and source in end.detail
        assert end.count == 1 and end.counts["lost_at_end"] == 2 and end.counts["lost"] == 3
        time.sleep(2.0)  # the stranger's end marker is not judged, then or later
        assert rec.status()["lost_at_end"] == 2
        sub.undeclare()
        rec.terminate()


# ----- faults ---------------------------------------------------------------------------------------

_DEPTH_ENCODING = "application/msgpack;fixstream.Depth/1"


def _malformed(i: int) -> tuple[bytes, str, str]:
    """The i-th bad payload, its encoding and the reason the recorder must give, derived here by hand."""
    good = EXAMPLES["Depth"].model_dump(mode="python")
    kind = i % 7
    if kind == 0:  # a msgpack map cut short: the unpacker runs out of input
        packed = msgpack.packb(good)
        return packed[: 1 + i % (len(packed) - 1)], _DEPTH_ENCODING, "bad_msgpack"
    if kind == 1:  # NaN in a float field
        return msgpack.packb({**good, "depth_m": float("nan")}), _DEPTH_ENCODING, "non_finite"
    if kind == 2:  # a string where a float (or an int) belongs
        bad = {**good, "depth_m": "35.5"} if i % 2 else {**good, "header": {**good["header"], "seq": "7"}}
        return msgpack.packb(bad), _DEPTH_ENCODING, "wrong_type"
    if kind == 3:
        return msgpack.packb({k: v for k, v in good.items() if k != "depth_m"}), _DEPTH_ENCODING, "missing_field"
    if kind == 4:
        return msgpack.packb({**good, "depth_ft": 116.5}), _DEPTH_ENCODING, "extra_field"
    if kind == 5:
        return msgpack.packb(good), "application/msgpack;fixstream.NoSuchModel/1", "unknown_schema"
    # 0xc1 is the one byte the msgpack spec never uses: whatever follows, it cannot be unpacked
    return b"\xc1" + os.urandom(1 + i % 40), _DEPTH_ENCODING, "bad_msgpack"


def test_malformed_flood_is_recorded_raw_counted_and_survived(router: str, tmp_path: Path) -> None:
    """Every bad payload is in the file byte for byte on fixstream/rejected/<key> with its reason; the recorder's own
    diagnostics stay aggregated: at most one per reason per diag_interval_s (so at most reasons x (elapsed / interval
    + 1) in all, where elapsed is measured here: a slow machine only widens the bound, it cannot break it)."""
    n_bad, every, interval_s = 1000, 10, 0.5
    diags: list[Diagnostic] = []
    env = {"FIXSTREAM_RECORDER_KEY_EXPR": "fixstream/sensor/**", "FIXSTREAM_RECORDER_DIAG_INTERVAL_S": str(interval_s)}
    good_key, bad_key = "fixstream/sensor/auv1/depth/good", "fixstream/sensor/auv1/depth/bad"
    sent_bad: list[tuple[bytes, str, str]] = []
    with recorder(router, tmp_path, instance="faults", **env) as rec:
        sub = rec.session.declare_subscriber(
            keys.diag("recorder", "faults"),
            lambda s: diags.append(codec.decode(s.payload.to_bytes(), str(s.encoding))),  # type: ignore[arg-type]
        )
        t0 = time.monotonic()
        expected: Counter[str] = Counter()
        good: list[Message] = []
        for i in range(n_bad):
            payload, encoding, reason = _malformed(i)
            rec.send_raw(bad_key, payload, encoding)
            sent_bad.append((payload, encoding, reason))
            expected[reason] += 1
            if i % every == 0:
                msg = restamp(EXAMPLES["Depth"], len(good), "test/good")
                rec.send(good_key, msg)
                good.append(msg)
        status = rec.wait_status(lambda s: s["counters"]["rejected"] >= n_bad and s["written"] >= len(good))
        assert rec.proc.poll() is None and rec.alive()
        assert status["counters"]["rejected_by_reason"] == dict(expected)
        assert status["counters"]["rejected"] == status["rejected_recorded"] == n_bad
        assert (status["written"], status["lost"]) == (len(good), 0)
        assert wait_until(lambda: set(expected) <= {d.reason for d in diags}, timeout=10)
        rec.terminate()
        elapsed = time.monotonic() - t0
        sub.undeclare()
    assert all(d.key == bad_key and d.service == "recorder" for d in diags)
    assert {d.reason: d.count for d in diags if d.count == expected[d.reason]} == dict(expected)  # final counts
    assert len(diags) <= len(expected) * (elapsed / interval_s + 1), (len(diags), elapsed)
    records = records_of(recording_files(rec.out_dir))
    assert {r.topic for r in records} == {good_key, REJECTED_PREFIX + bad_key}
    assert [decode_record(r) for r in records if r.topic == good_key] == good
    rejected = [decode_rejected(r) for r in records if is_rejected(r)]
    assert [(x.payload, x.encoding, x.reason) for x in rejected] == sent_bad
    assert all(x.key == bad_key and x.detail for x in rejected)

    # a replay puts the same bytes back on the original keys, in the recorded order
    (path,) = recording_files(rec.out_dir)
    recorded = [
        (x.key, x.payload, x.encoding)
        if is_rejected(r) and (x := decode_rejected(r))
        else (r.topic, codec.encode(decode_record(r)), codec.encoding_of(type(decode_record(r))))
        for r in records
    ]
    collector = Collector(router)
    try:
        done = subprocess.run(
            fixstream_cmd("play", str(path), "--rate", "0", "--connect", router, "--linger", "0.3"),
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert done.returncode == 0, done.stderr
        assert wait_until(lambda: len(collector.samples) >= len(recorded), timeout=20)
        replayed = [(k, p, e) for k, p, e, _ in collector.samples if k.startswith("fixstream/sensor/")]
    finally:
        collector.close()
    assert replayed == recorded
