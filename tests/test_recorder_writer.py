"""The recorder's MCAP writer in-process: layout, chunk flushing, rotation, path confinement."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from mcap.reader import make_reader
from pydantic import ValidationError
from samples import EXAMPLES, available_examples

from schemas import Message
from schemas.export import json_schema
from services.recorder.settings import RecorderSettings
from services.recorder.writer import RotatingMcapWriter
from shared.mcap_io import MAGIC, Rejected, decode_record, decode_rejected, iter_records, recording_files


class FakeClock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def examples() -> dict[str, Message]:
    """One example of every model that has one (completeness is the contract test's business)."""
    return available_examples()


def stamped(msg: Message, seq: int) -> Message:
    return msg.model_copy(update={"header": msg.header.model_copy(update={"seq": seq, "stamp_ns": 10 + seq})})


def test_file_layout_is_what_foxglove_reads(tmp_path: Path) -> None:
    w = RotatingMcapWriter(tmp_path, compression="lz4", chunk_size_bytes=4096)
    sent = [(f"fixstream/test/{name}", stamped(m, i)) for i, (name, m) in enumerate(examples().items())]
    for key, msg in sent:
        w.write(key, msg, rx_time_ns=123)
    path = w.finish()
    assert path is not None and path.parent == tmp_path.resolve()
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == len(sent)
        assert {c.compression for c in summary.chunk_indexes} == {"lz4"}
        for schema in summary.schemas.values():
            name = schema.name.removeprefix("fixstream.")
            assert schema.encoding == "jsonschema"
            assert json.loads(schema.data) == json_schema(name)
        topics = {c.topic: c for c in summary.channels.values()}
        assert set(topics) == {k for k, _ in sent}
        for key, msg in sent:
            assert topics[key].message_encoding == "json"
            assert topics[key].metadata == {"zenoh_encoding": f"application/msgpack;{type(msg).schema_id()}"}
    records = list(iter_records(path))
    assert [(r.topic, decode_record(r)) for r in records] == sent
    assert [r.publish_time_ns for r in records] == [m.header.stamp_ns for _, m in sent]


def test_open_chunk_is_written_after_chunk_flush_s(tmp_path: Path) -> None:
    clock = FakeClock()
    w = RotatingMcapWriter(tmp_path, chunk_size_bytes=1 << 20, chunk_flush_s=0.5, clock=clock)
    depth = EXAMPLES["Depth"]
    for i in range(5):
        w.write("fixstream/test/depth", stamped(depth, i), rx_time_ns=i)
    path = w.current_path
    assert path is not None
    assert list(iter_records(path)) == []  # still in the open chunk, nothing on disk yet
    clock.t += 0.4
    w.poll()
    assert list(iter_records(path)) == []
    clock.t += 0.1
    w.poll()
    assert [decode_record(r).header.seq for r in iter_records(path)] == [0, 1, 2, 3, 4]  # file still open
    assert not path.read_bytes().endswith(MAGIC)
    w.write("fixstream/test/depth", stamped(depth, 5), rx_time_ns=5)
    w.finish()
    assert [decode_record(r).header.seq for r in iter_records(path)] == [0, 1, 2, 3, 4, 5]
    assert path.read_bytes().endswith(MAGIC)


def test_rotation_by_size_and_by_duration(tmp_path: Path) -> None:
    clock = FakeClock()
    by_size = RotatingMcapWriter(
        tmp_path / "size", chunk_size_bytes=1024, rotate_size_bytes=3000, compression="none", clock=clock
    )
    truth = EXAMPLES["Truth"]
    for i in range(200):
        by_size.write("fixstream/truth/auv1", stamped(truth, i), rx_time_ns=i)
    by_size.finish()
    files = recording_files(tmp_path / "size")
    assert files == by_size.files_written and len(files) >= 3
    seqs = [decode_record(r).header.seq for p in files for r in iter_records(p)]
    assert seqs == list(range(200))

    by_age = RotatingMcapWriter(tmp_path / "age", rotate_duration_s=10.0, clock=clock)
    for i in range(30):
        by_age.write("fixstream/truth/auv1", stamped(truth, i), rx_time_ns=i)
        clock.t += 1.0  # 30 s of messages at 1 Hz -> three files of 10 messages
    by_age.poll()
    by_age.finish()
    files = recording_files(tmp_path / "age")
    assert [len(list(iter_records(p))) for p in files] == [10, 10, 10]


def test_no_file_is_overwritten(tmp_path: Path) -> None:
    now = datetime.now(UTC)
    taken = {f"fixstream_{(now + timedelta(seconds=s)):%Y%m%dT%H%M%SZ}_000.mcap" for s in (0, 1)}
    for name in taken:
        (tmp_path / name).write_bytes(b"precious")
    w = RotatingMcapWriter(tmp_path)
    w.write("fixstream/test/depth", EXAMPLES["Depth"], rx_time_ns=1)
    path = w.finish()
    assert path is not None and path.name not in taken and path.name.endswith("_001.mcap")
    assert all((tmp_path / name).read_bytes() == b"precious" for name in taken)


@pytest.mark.parametrize("prefix", ["../escape", "a/b", "..", "/abs", ".hidden", "x\\y", ""])
def test_file_prefix_cannot_leave_out_dir(tmp_path: Path, prefix: str) -> None:
    with pytest.raises(ValidationError, match="file_prefix"):
        RecorderSettings(out_dir=tmp_path, file_prefix=prefix)
    if "/" in prefix or ".." in prefix or not prefix:
        with pytest.raises(ValueError, match="plain file name"):
            RotatingMcapWriter(tmp_path, prefix=prefix)


def test_settings_from_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("FIXSTREAM_RECORDER_OUT_DIR", str(tmp_path))
    monkeypatch.setenv("FIXSTREAM_RECORDER_COMPRESSION", "lz4")
    monkeypatch.setenv("FIXSTREAM_RECORDER_ROTATE_DURATION_S", "60")
    monkeypatch.setenv("FIXSTREAM_RECORDER_INSTANCE", "r2")
    s = RecorderSettings.load(chunk_flush_s=0.25)
    assert isinstance(s, RecorderSettings)
    assert (s.out_dir, s.compression, s.rotate_duration_s, s.instance, s.chunk_flush_s) == (
        tmp_path,
        "lz4",
        60.0,
        "r2",
        0.25,
    )
    monkeypatch.setenv("FIXSTREAM_RECORDER_COMPRESSION", "bzip2")
    with pytest.raises(ValidationError, match="compression"):
        RecorderSettings.load()


def test_time_fields_rejected_channel_metadata_and_attachments_in_every_file(tmp_path: Path) -> None:
    """log_time = publish_time = header.stamp_ns whatever the receive time; a rejected payload keeps its bytes and
    encoding; metadata and attachments are in each file of a rotation (read back with the official reader)."""
    clock = FakeClock()
    w = RotatingMcapWriter(tmp_path, rotate_duration_s=10.0, clock=clock, metadata={"who": "test"})
    w.put_attachment("scenario/s.yaml", "application/yaml", b"name: s\n", 0)
    depth = EXAMPLES["Depth"]
    bad = Rejected("fixstream/sensor/a/depth/d", "application/msgpack;fixstream.Depth/1", "non_finite", "NaN", b"\xc1x")
    w.write("fixstream/sensor/a/depth/d", stamped(depth, 0), rx_time_ns=999_999)
    w.write_rejected(bad, stamp_ns=11)
    w.put_metadata("fixstream.run", {"scenario": "s"})
    clock.t += 10.0  # rotation by duration at the next write
    w.write("fixstream/sensor/a/depth/d", stamped(depth, 1), rx_time_ns=5)
    w.finish()
    files = recording_files(tmp_path)
    assert len(files) == 2
    for path in files:
        with path.open("rb") as f:
            reader = make_reader(f)
            assert {m.name: m.metadata for m in reader.iter_metadata()} == {
                "fixstream.recorder": {"who": "test"},
                "fixstream.run": {"scenario": "s"},
            }
            assert [(a.name, a.data) for a in reader.iter_attachments()] == [("scenario/s.yaml", b"name: s\n")]
    first = list(iter_records(files[0]))
    assert [(r.log_time_ns, r.publish_time_ns) for r in first] == [(10, 10), (11, 11)]  # stamps, not receive times
    assert decode_rejected(first[1]) == Rejected(bad.key, bad.encoding, bad.reason, bad.detail, bad.payload, 0)
    assert first[1].topic == "fixstream/rejected/fixstream/sensor/a/depth/d"
    assert [r.log_time_ns for r in iter_records(files[1])] == [11]
