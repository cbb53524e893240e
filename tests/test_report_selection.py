"""One recording per report unless the user asks for several (issue 17, item 9).

The recorder names its files ``<prefix>_<UTC stamp>_<nnn>.mcap``, ``nnn`` counting up over one run's rotated files
and starting again at 000 in the next run. So a directory holding two runs, the first rotated once, is two
recordings: ``fixstream report DIR`` reports the newest and says which others it left out; naming files of two
recordings is refused with a message listing them; ``--all`` merges them, and says so.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from itertools import pairwise
from pathlib import Path

import pytest
from conftest import REPO, fixstream_cmd
from hypothesis import given
from hypothesis import strategies as st

from schemas import Header, Truth
from services.recorder.writer import RotatingMcapWriter
from shared import keys
from tools.report.offline import T0_NS, marker
from tools.report.reading import ReportError, recordings, select_recording

OLD_A = "fixstream_20260101T100000Z_000.mcap"
OLD_B = "fixstream_20260101T101000Z_001.mcap"  # the first run's rotated second file
NEW = "fixstream_20260101T120000Z_000.mcap"


def tiny_recording(out: Path, n: int = 40) -> Path:
    """A start marker and ``n`` truth samples of one platform at 10 Hz: ``n + 1`` messages."""
    writer = RotatingMcapWriter(out, prefix="t")
    writer.write(keys.scenario("x"), marker("x", "start", 0, 0), T0_NS)
    for i in range(n):
        header = Header(stamp_ns=i * 100_000_000, frame_id="local_enu", source="player/default", seq=i)
        writer.write(keys.truth("auv1"), Truth(header=header, platform="auv1", position_m=[i, 0.0, -5.0]), T0_NS)
    writer.finish()
    (path,) = writer.files_written
    return path


def report(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        fixstream_cmd("report", *args, "--no-progress", "--workers", "1"),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.fixture(scope="module")
def directory(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("selection")
    one = tiny_recording(tmp / "src")
    d = tmp / "recordings"
    d.mkdir()
    for name in (OLD_A, OLD_B, NEW):
        shutil.copy2(one, d / name)
    return d


def test_files_group_into_recordings_by_the_recorders_names(directory: Path) -> None:
    files = sorted(directory.glob("*.mcap"))
    assert [[p.name for p in g] for g in recordings(files)] == [[OLD_A, OLD_B], [NEW]]
    other = [Path("notes.mcap"), Path("fixstream_20260101T100000Z_000.mcap"), Path("x_20260101T100000Z_001.mcap")]
    assert len(recordings(other)) == 3  # a foreign name, and a prefix change, start recordings of their own


@given(st.lists(st.integers(min_value=0, max_value=3), min_size=1, max_size=12))
def test_grouping_follows_the_index_counting_up(indices: list[int]) -> None:
    """A file joins the previous one's recording exactly when its index is the previous index + 1
    (independently: the number of recordings is 1 + the number of places where it is not)."""
    files = [Path(f"rec_20260101T{i:06d}Z_{n:03d}.mcap") for i, n in enumerate(indices)]
    groups = recordings(files)
    assert [f for g in groups for f in g] == files
    assert len(groups) == 1 + sum(1 for a, b in pairwise(indices) if b != a + 1)


def test_a_directory_means_its_newest_recording_and_says_which_it_left_out(directory: Path) -> None:
    files, notes = select_recording([directory])
    assert [f.name for f in files] == [NEW]
    (note,) = notes
    assert "2 recordings" in note and NEW in note and OLD_A in note and "--all" in note
    files, notes = select_recording([directory], merge=True)
    assert [f.name for f in files] == [OLD_A, OLD_B, NEW] and "merged" in notes[0]
    files, notes = select_recording([directory / OLD_A, directory / OLD_B])  # one recording's rotated files
    assert len(files) == 2 and notes == []
    with pytest.raises(ReportError, match=r"2 recordings given .*--all"):
        select_recording([directory / OLD_A, directory / NEW])


def test_the_cli_reports_the_newest_refuses_a_mix_and_merges_on_request(directory: Path, tmp_path: Path) -> None:
    done = report(str(directory), "--out", str(tmp_path / "newest"))
    assert done.returncode == 0, done.stderr
    assert f"reported the newest, {NEW}" in done.stderr and OLD_A in done.stderr
    metrics = json.loads((tmp_path / "newest" / "metrics.json").read_text())
    assert metrics["run"]["files"] == [NEW] and metrics["run"]["messages"] == 41
    assert any("reported the newest" in n for n in metrics["notes"])  # on the page too

    mixed = report(str(directory / OLD_A), str(directory / NEW), "--out", str(tmp_path / "mixed"))
    assert mixed.returncode == 2 and "Traceback" not in mixed.stderr
    (line,) = [x for x in mixed.stderr.splitlines() if x.strip()]
    assert line.startswith("fixstream report: 2 recordings given") and OLD_A in line and NEW in line

    merged = report(str(directory), "--all", "--out", str(tmp_path / "all"))
    assert merged.returncode == 0, merged.stderr
    metrics = json.loads((tmp_path / "all" / "metrics.json").read_text())
    assert metrics["run"]["files"] == [OLD_A, OLD_B, NEW] and metrics["run"]["messages"] == 3 * 41
