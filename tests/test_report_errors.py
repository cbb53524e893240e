"""``fixstream report`` on recordings it cannot use: a clear one-line error naming the file and the problem,
exit status 2, never a traceback (issue 8). A truncated file (no footer: a recorder killed mid-write) is an
error unless ``--allow-truncated``, which reports its complete chunks and says so."""

from __future__ import annotations

import json
import struct
import subprocess
from pathlib import Path

from conftest import REPO, fixstream_cmd
from mcap.writer import CompressionType, Writer

from schemas import Header, Truth
from services.recorder.writer import RotatingMcapWriter
from shared import keys
from tools.report.offline import T0_NS, marker


def report(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        fixstream_cmd("report", *args, "--no-progress"), cwd=REPO, capture_output=True, text=True, timeout=120
    )


def assert_clear_error(done: subprocess.CompletedProcess[str], *fragments: str) -> None:
    assert done.returncode == 2, (done.returncode, done.stdout, done.stderr)
    assert "Traceback" not in done.stderr, done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("fixstream report: "), done.stderr
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


def small_recording(tmp_path: Path, n: int = 400) -> Path:
    """A finalised recording of many small chunks: markers and a platform's truth at 10 Hz."""
    writer = RotatingMcapWriter(tmp_path / "rec", prefix="t", chunk_size_bytes=4096)
    writer.write(keys.scenario("x"), marker("x", "start", 0, 0), T0_NS)
    for i in range(n):
        stamp = i * 100_000_000
        truth = Truth(
            header=Header(stamp_ns=stamp, frame_id="local_enu", source="player/default", seq=i),
            platform="auv1",
            position_m=[float(i), 2.0 * i, -30.0],
        )
        writer.write(keys.truth("auv1"), truth, T0_NS + stamp)
    writer.finish()
    (path,) = writer.files_written
    return path


def records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of the top-level records after the magic."""
    out = []
    pos = 8
    while pos + 9 <= len(data):
        opcode = data[pos]
        (length,) = struct.unpack("<Q", data[pos + 1 : pos + 9])
        out.append((pos, opcode, length))
        if opcode == 0x02:  # footer
            break
        pos += 9 + length
    return out


def test_a_good_small_recording_reports(tmp_path: Path) -> None:
    path = small_recording(tmp_path)
    done = report(str(path), "--out", str(tmp_path / "out"))
    assert done.returncode == 0, done.stderr
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["run"]["messages"] == 401


def test_missing_empty_and_non_mcap_files(tmp_path: Path) -> None:
    assert_clear_error(report(str(tmp_path / "nope.mcap")), str(tmp_path / "nope.mcap"), "no such file")
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    assert_clear_error(report(str(empty)), str(empty), "empty file")
    text = tmp_path / "notes.mcap"
    text.write_text("this is not a recording\n" * 10)
    assert_clear_error(report(str(text)), str(text), "not an MCAP file")
    (tmp_path / "emptydir").mkdir()
    assert_clear_error(report(str(tmp_path / "emptydir")), "no .mcap file")


def test_truncated_file_is_an_error_unless_allowed(tmp_path: Path) -> None:
    path = small_recording(tmp_path)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 6 // 10])
    assert_clear_error(report(str(cut)), str(cut), "truncated", "--allow-truncated")
    done = report(str(cut), "--allow-truncated", "--out", str(tmp_path / "out"))
    assert done.returncode == 0, done.stderr
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert 0 < metrics["run"]["messages"] < 401
    assert any("truncated" in note for note in metrics["notes"])


def test_corrupt_chunk_names_the_offset(tmp_path: Path) -> None:
    path = small_recording(tmp_path)
    data = bytearray(path.read_bytes())
    chunks = [off for off, op, _ in records(bytes(data)) if op == 0x06]
    assert len(chunks) > 3
    off = chunks[1]
    for i in range(off + 9 + 80, off + 9 + 120):  # inside the compressed records of the second chunk
        data[i] ^= 0x5A
    bad = tmp_path / "corrupt.mcap"
    bad.write_bytes(bytes(data))
    assert_clear_error(report(str(bad)), str(bad), "corrupt chunk", f"offset {off}")


def test_invalid_message_names_topic_and_field(tmp_path: Path) -> None:
    bad = tmp_path / "invalid.mcap"
    with bad.open("wb") as f:
        w = Writer(f, compression=CompressionType.NONE)
        w.start()
        sid = w.register_schema("fixstream.Truth", "jsonschema", b"{}")
        cid = w.register_channel("fixstream/truth/auv1", "json", sid)
        msg = {"header": {"stamp_ns": 0, "frame_id": "", "source": "", "seq": 0}, "platform": "auv1",
               "position_m": [1.0, 2.0]}  # fmt: skip
        w.add_message(cid, log_time=1, publish_time=0, data=json.dumps(msg).encode())
        w.finish()
    assert_clear_error(report(str(bad)), str(bad), "fixstream/truth/auv1", "Truth.position_m")


def test_unknown_scenario_argument(tmp_path: Path) -> None:
    path = small_recording(tmp_path)
    assert_clear_error(report(str(path), "--scenario", str(tmp_path / "none.yaml")), "--scenario", "none.yaml")
