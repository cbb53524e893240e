"""shared.mcap_io against files written by the official mcap Writer (not by the recorder under test)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from samples import EXAMPLES

from schemas.export import json_schema
from shared.mcap_io import (
    MAGIC,
    MAX_JSON_MESSAGE_BYTES,
    McapReadError,
    Record,
    count_by_topic,
    decode_record,
    iter_records,
    recover,
    scan,
)

MODELS_USED = ("Depth", "Heading", "Fix", "Truth")
PER_CHUNK = 10
CHUNKS = 3


def _message(i: int):  # type: ignore[no-untyped-def]
    name = MODELS_USED[i % len(MODELS_USED)]
    base = EXAMPLES[name]
    header = base.header.model_copy(update={"seq": i, "stamp_ns": 1_000_000_000 + i})
    return f"fixstream/test/{name.lower()}", name, base.model_copy(update={"header": header})


def write_file(
    path: Path, compression: CompressionType = CompressionType.ZSTD, chunked: bool = True
) -> list[tuple[str, object]]:
    """CHUNKS chunks of PER_CHUNK messages each (closed with Writer.flush()); returns (topic, msg) sent."""
    sent: list[tuple[str, object]] = []
    with path.open("wb") as f:
        w = Writer(f, chunk_size=1 << 20, compression=compression, use_chunking=chunked)
        w.start()
        schema_ids: dict[str, int] = {}
        channel_ids: dict[str, int] = {}
        for i in range(CHUNKS * PER_CHUNK):
            topic, name, msg = _message(i)
            if name not in schema_ids:
                schema_ids[name] = w.register_schema(
                    f"fixstream.{name}", "jsonschema", json.dumps(json_schema(name)).encode()
                )
            if topic not in channel_ids:
                channel_ids[topic] = w.register_channel(
                    topic, "json", schema_ids[name], {"zenoh_encoding": f"application/msgpack;{type(msg).schema_id()}"}
                )
            w.add_message(channel_ids[topic], log_time=5_000 + i, data=msg.model_dump_json().encode(), publish_time=i)
            sent.append((topic, msg))
            if i % PER_CHUNK == PER_CHUNK - 1:
                w.flush()
        w.finish()
    return sent


def chunk_spans(path: Path) -> list[tuple[int, int]]:
    """(start offset, end offset) of every chunk record, from the official reader's summary."""
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return sorted((c.chunk_start_offset, c.chunk_start_offset + c.chunk_length) for c in summary.chunk_indexes)


@pytest.mark.parametrize("compression", [CompressionType.ZSTD, CompressionType.LZ4, CompressionType.NONE])
def test_finalised_file_matches_official_reader(tmp_path: Path, compression: CompressionType) -> None:
    path = tmp_path / "ok.mcap"
    sent = write_file(path, compression)
    records = list(iter_records(path))
    with path.open("rb") as f:
        official = [(c.topic, m.log_time, m.publish_time, m.data) for _, c, m in make_reader(f).iter_messages()]
    assert [(r.topic, r.log_time_ns, r.publish_time_ns, r.data) for r in records] == official
    assert len(records) == CHUNKS * PER_CHUNK
    assert [(r.topic, decode_record(r)) for r in records] == sent
    for r in records:
        assert r.schema_encoding == "jsonschema" and r.message_encoding == "json"
        assert r.schema_name == f"fixstream.{type(decode_record(r)).__name__}"
        assert r.channel_metadata["zenoh_encoding"] == f"application/msgpack;{type(decode_record(r)).schema_id()}"
    expected_counts: dict[str, int] = {}
    for topic, _ in sent:
        expected_counts[topic] = expected_counts.get(topic, 0) + 1
    assert count_by_topic(path) == expected_counts


def test_unchunked_file_is_read(tmp_path: Path) -> None:
    path = tmp_path / "flat.mcap"
    sent = write_file(path, chunked=False)
    assert [(r.topic, decode_record(r)) for r in iter_records(path)] == sent


def test_truncated_mid_chunk_yields_the_complete_chunks(tmp_path: Path) -> None:
    path = tmp_path / "full.mcap"
    sent = write_file(path)
    spans = chunk_spans(path)
    assert len(spans) == CHUNKS
    start, end = spans[2]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: (start + end) // 2])
    records = list(iter_records(cut))
    assert [(r.topic, decode_record(r)) for r in records] == sent[: 2 * PER_CHUNK]


def test_every_truncation_point_yields_a_prefix_of_complete_chunks(tmp_path: Path) -> None:
    """Cut the file after the header: never an exception, always whole chunks, in order.

    Every byte within 24 bytes of a chunk boundary and of the end, every 9th byte elsewhere (time budget).
    """
    path = tmp_path / "full.mcap"
    write_file(path, CompressionType.LZ4)
    data = path.read_bytes()
    full = [(r.topic, r.data) for r in iter_records(path)]
    spans = chunk_spans(path)
    edges = [e for span in spans for e in span] + [len(data)]
    cuts = {n for n in range(spans[0][0], len(data), 9)}
    cuts |= {n for e in edges for n in range(e - 24, e + 25) if spans[0][0] <= n < len(data)}
    cut = tmp_path / "cut.mcap"
    for n in sorted(cuts):
        cut.write_bytes(data[:n])
        got = [(r.topic, r.data) for r in iter_records(cut)]
        complete = sum(1 for _, end in spans if end <= n)
        assert got == full[: complete * PER_CHUNK], f"cut at byte {n}"


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(McapReadError, match="no such file") as info:
        iter_records(tmp_path / "nope.mcap")
    assert info.value.reason == "missing"


def test_empty_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    path.write_bytes(b"")
    with pytest.raises(McapReadError, match=r"empty file \(0 bytes\)") as info:
        list(iter_records(path))
    assert str(path) in str(info.value)


def test_non_mcap_file(tmp_path: Path) -> None:
    path = tmp_path / "notes.mcap"
    path.write_text("these are not the bytes you are looking for\n")
    with pytest.raises(McapReadError, match="not an MCAP file: starts with 74 68 65 73") as info:
        list(iter_records(path))
    assert info.value.reason == "not_mcap"


@pytest.mark.parametrize("keep", [3, 8, 12, 20])
def test_truncated_inside_header(tmp_path: Path, keep: int) -> None:
    full = tmp_path / "full.mcap"
    write_file(full)
    data = full.read_bytes()
    assert data.startswith(MAGIC)
    path = tmp_path / "head.mcap"
    path.write_bytes(data[:keep])
    with pytest.raises(McapReadError, match="truncated inside the header") as info:
        list(iter_records(path))
    assert info.value.reason == "truncated_header"


def test_header_only_file_yields_nothing(tmp_path: Path) -> None:
    """A recorder killed before its first chunk leaves magic + header: a valid, empty recording."""
    full = tmp_path / "full.mcap"
    write_file(full)
    first_chunk = chunk_spans(full)[0][0]
    path = tmp_path / "header_only.mcap"
    path.write_bytes(full.read_bytes()[:first_chunk])
    assert list(iter_records(path)) == []


def test_corrupt_chunk_is_reported_with_its_offset(tmp_path: Path) -> None:
    path = tmp_path / "full.mcap"
    sent = write_file(path)
    start, end = chunk_spans(path)[1]
    data = bytearray(path.read_bytes())
    for i in range(end - 24, end - 8):  # inside the compressed records of the second chunk
        data[i] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    got: list[Record] = []
    with pytest.raises(McapReadError, match=f"corrupt chunk at byte offset {start}"):
        got.extend(iter_records(bad))
    assert [(r.topic, decode_record(r)) for r in got] == sent[:PER_CHUNK]


def test_decode_record_rejects_bad_json_and_unknown_schema() -> None:
    good = Record(
        topic="fixstream/x",
        schema_name="fixstream.Depth",
        schema_encoding="jsonschema",
        message_encoding="json",
        log_time_ns=1,
        publish_time_ns=1,
        data=EXAMPLES["Depth"].model_dump_json().encode(),
    )
    assert decode_record(good) == EXAMPLES["Depth"]
    wrong_type = json.loads(good.data)
    wrong_type["depth_m"] = "35.5"
    bad = Record(**{**good.__dict__, "data": json.dumps(wrong_type).encode()})
    with pytest.raises(McapReadError, match=r"fixstream/x: Depth\.depth_m") as info:
        decode_record(bad)
    assert info.value.reason == "invalid_message"
    unknown = Record(**{**good.__dict__, "schema_name": "fixstream.NoSuchModel"})
    with pytest.raises(McapReadError, match="no model named 'NoSuchModel'"):
        decode_record(unknown)


def test_a_message_too_large_for_any_service_is_refused_before_it_is_decoded() -> None:
    """A hostile file's one 50 MB JSON message cost a replay and a report 1.1 GB each: it is refused by its size,
    before the JSON parser or pydantic see it (what they would build is what cost the memory)."""
    import tracemalloc

    doc = EXAMPLES["Depth"].model_dump(mode="json")
    doc["padding"] = "x" * (MAX_JSON_MESSAGE_BYTES + 1)  # would also fail validation: extra field
    data = json.dumps(doc).encode()
    record = Record("fixstream/x", "fixstream.Depth", "jsonschema", "json", 1, 1, data)
    tracemalloc.start()
    try:
        with pytest.raises(McapReadError, match="not decoded") as info:
            decode_record(record)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert info.value.reason == "too_large"
    assert peak < 1_000_000  # nothing of its size was built
    fits = Record(**{**record.__dict__, "data": EXAMPLES["Depth"].model_dump_json().encode()})
    assert decode_record(fits) == EXAMPLES["Depth"]


def test_scan_and_recover_a_file_cut_inside_its_last_chunk(tmp_path: Path) -> None:
    """scan() tells finalised from truncated and counts what is readable; recover() writes a finalised file that the
    official reader reads message for message (times and sequence kept), metadata and attachments included."""
    full = tmp_path / "full.mcap"
    sent = write_file(full)
    spans = chunk_spans(full)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full.read_bytes()[: (spans[2][0] + spans[2][1]) // 2])
    whole, part = scan(full), scan(cut)
    assert whole.finalised and whole.tail_bytes == 0 and whole.messages == len(sent) and whole.chunks == CHUNKS
    assert not part.finalised and part.tail_bytes == cut.stat().st_size - spans[2][0]
    assert part.messages == 2 * PER_CHUNK and dict(part.compression) == {"zstd": 2}
    assert part.start_ns == 5_000 and part.end_ns == 5_000 + 2 * PER_CHUNK - 1
    out = tmp_path / "recovered.mcap"
    again = recover(cut, out)
    assert again.finalised and again.messages == part.messages
    with out.open("rb") as f:
        got = [(c.topic, m.log_time, m.publish_time, m.sequence, m.data) for _, c, m in make_reader(f).iter_messages()]
    with full.open("rb") as f:
        want = [(c.topic, m.log_time, m.publish_time, m.sequence, m.data) for _, c, m in make_reader(f).iter_messages()]
    assert got == want[: 2 * PER_CHUNK]
    with pytest.raises(FileExistsError):
        recover(cut, out)  # never overwrites


def test_metadata_and_attachments_are_read_in_file_order(tmp_path: Path) -> None:
    path = tmp_path / "meta.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("fixstream.run", {"scenario": "s", "seed": "3"})
        w.add_attachment(create_time=1, log_time=2, name="scenario/s.yaml", media_type="application/yaml", data=b"a: 1")
        w.finish()
    info = scan(path)
    assert [(m.name, dict(m.metadata)) for m in info.metadata] == [("fixstream.run", {"scenario": "s", "seed": "3"})]
    assert [(a.name, a.media_type, a.data, a.log_time_ns) for a in info.attachments] == [
        ("scenario/s.yaml", "application/yaml", b"a: 1", 2)
    ]


def test_info_escapes_what_the_file_says_and_keeps_what_is_printable(tmp_path: Path) -> None:
    """Names, topics and metadata come from the file: a hostile one's terminal escapes once reached the terminal."""
    from shared.mcap_io import scan
    from tools.cli.info import describe

    path = tmp_path / "meta.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start(profile="", library="test\x1b]0;title\x07")
        schema = w.register_schema(name="fixstream.Depth", encoding="jsonschema", data=b"{}")
        topic = "fixstream/sensor/\x1b[2Jp/depth/d0"
        ch = w.register_channel(topic=topic, message_encoding="json", schema_id=schema)
        w.add_message(ch, log_time=1, data=EXAMPLES["Depth"].model_dump_json().encode(), publish_time=1)
        w.add_metadata("run", {"frame_id": "\x1b[31mred\x1b[0m", "note": "Привет, τ = 5 s"})
        w.finish()
    text = describe(scan(path))
    assert not any((ord(c) < 32 and c != "\n") or ord(c) == 127 for c in text)
    assert "\\x1b[31mred\\x1b[0m" in text and "\\x1b[2J" in text and "\\x07" in text
    assert "Привет, τ = 5 s" in text  # printable text from any script stays as it is


def test_info_lists_every_model_a_key_was_written_with(tmp_path: Path) -> None:
    """A key written with two models (a stray Heading among 3 Depth) once showed as 4 Depth, Heading nowhere."""
    from shared.mcap_io import scan
    from tools.cli.info import as_dict, describe

    path = tmp_path / "two.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start(profile="", library="test")
        key = "fixstream/sensor/p/depth/d0"
        channels = {}
        for name in ("Depth", "Heading"):
            schema = w.register_schema(name=f"fixstream.{name}", encoding="jsonschema", data=b"{}")
            channels[name] = w.register_channel(topic=key, message_encoding="json", schema_id=schema)
        for i, name in enumerate(["Depth", "Depth", "Heading", "Depth"]):
            w.add_message(channels[name], log_time=i, data=EXAMPLES[name].model_dump_json().encode(), publish_time=i)
        w.finish()
    s = scan(path)
    text = describe(s)
    assert "3 fixstream.Depth, 1 fixstream.Heading (json)" in text, text
    assert "Schemas (2): fixstream.Depth, fixstream.Heading" in text
    assert as_dict(s)["topics"][key]["schemas"] == {"fixstream.Depth": 3, "fixstream.Heading": 1}


def test_recover_keeps_channels_that_differ_only_in_metadata_or_schema_data(tmp_path: Path) -> None:
    """recover() keyed channels by (topic, schema name, encoding): two channels of one key declaring Depth/1 and
    Depth/99 became one Depth/1, and a replay of the recovered file published what the original's skips."""
    src = tmp_path / "two.mcap"
    key = "fixstream/sensor/p/depth/d0"
    with src.open("wb") as f:
        w = Writer(f)
        w.start(profile="", library="test")
        s1 = w.register_schema(name="fixstream.Depth", encoding="jsonschema", data=b"{}")
        s2 = w.register_schema(name="fixstream.Depth", encoding="jsonschema", data=b'{"title": "other"}')
        metas = [{"zenoh_encoding": "application/msgpack;fixstream.Depth/1"}, {"zenoh_encoding": "x/99"}, {}]
        chans = [w.register_channel(key, "json", s, m) for s, m in ((s1, metas[0]), (s1, metas[1]), (s2, metas[2]))]
        for i, ch in enumerate(chans * 2):
            w.add_message(ch, log_time=i, data=EXAMPLES["Depth"].model_dump_json().encode(), publish_time=i)
        w.finish()
    out = tmp_path / "recovered.mcap"
    recover(src, out)

    def channels(path: Path) -> list[tuple[dict[str, str], bytes]]:
        return [(dict(r.channel_metadata), r.schema_data) for r in iter_records(path)]

    assert channels(out) == channels(src)
    assert len({(tuple(m.items()), d) for m, d in channels(out)}) == 3
