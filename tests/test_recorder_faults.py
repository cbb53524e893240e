"""The recorder under faults, over real processes: SIGKILL mid-run (what is lost against what it calls durable), the
killed file made readable by the standard readers (``fixstream info --recover``; the ``mcap`` package and, when node
is present, ``@mcap/core``'s indexed reader as Foxglove uses it), sequence numbers at their extremes, and scenario
names from the network that point outside the scenario directory."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import tempfile
from pathlib import Path

import msgpack
import pytest
from conftest import REPO, fixstream_cmd
from mcap.reader import make_reader
from recorder_support import recorder, restamp
from samples import EXAMPLES

from schemas import Header, ScenarioMarker
from schemas.base import MAX_SEQ
from services.recorder.run_context import find_scenario
from shared import codec, keys
from shared.mcap_io import MAGIC, decode_record, iter_records, recording_files, scan

pytestmark = pytest.mark.e2e

KEY = "fixstream/sensor/auv1/depth/d0"


def test_sigkill_loses_nothing_it_called_durable_and_recover_makes_it_standard(router: str, tmp_path: Path) -> None:
    """Phase 1 is sent and waited for until the recorder reports it durable (on disk in closed chunks); phase 2 is
    sent and the recorder killed at once. The file must hold a gap-free prefix of what was sent, at least every
    message reported durable before the kill; what is lost is at most what was not durable yet (the FIFO and the
    open chunk, docs/recorder.md). ``fixstream info --recover`` then gives a finalised file the official reader
    reads message for message."""
    env = {"FIXSTREAM_RECORDER_CHUNK_FLUSH_S": "0.3", "FIXSTREAM_RECORDER_KEY_EXPR": "fixstream/sensor/**"}
    first = [restamp(EXAMPLES["Depth"], i, "test/depth") for i in range(2000)]
    second = [restamp(EXAMPLES["Depth"], len(first) + i, "test/depth") for i in range(3000)]
    with recorder(router, tmp_path, **env) as rec:
        for msg in first:
            rec.send(KEY, msg)
        # the promise: within chunk_flush_s of being written, a message is in a closed chunk on disk
        status = rec.wait_status(lambda s: s["durable"] >= len(first) and s["unflushed_age_s"] == 0)
        path = Path(status["current_file"])
        for msg in second:
            rec.send(KEY, msg)
        before_kill = rec.status()
        rec.proc.kill()
        assert rec.proc.wait(timeout=10) == -signal.SIGKILL
    assert not path.read_bytes().endswith(MAGIC)  # really not finalised
    got = [decode_record(r) for r in iter_records(path)]
    assert got == (first + second)[: len(got)]  # a prefix: nothing in the middle is missing
    assert len(got) >= max(len(first), before_kill["durable"])
    assert (
        before_kill["counters"]["received"] - len(got) <= before_kill["counters"]["received"] - before_kill["durable"]
    )
    info = scan(path)
    assert not info.finalised and info.messages == len(got)
    with path.open("rb") as f, pytest.raises(Exception):  # noqa: B017 - the footer reader's own error types
        list(make_reader(f).iter_messages())  # what issue 14 found: the standard reader needs the footer

    out = tmp_path / "recovered.mcap"
    done = subprocess.run(
        fixstream_cmd("info", str(path), "--recover", "--out", str(out)), cwd=REPO, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert f"recovered {len(got)} messages" in done.stdout and "finalised" in done.stdout
    with out.open("rb") as f:
        reader = make_reader(f)
        official = [(c.topic, m.data) for _, c, m in reader.iter_messages()]
        meta = {m.name for m in reader.iter_metadata()}
    assert official == [(KEY, msg.model_dump_json().encode()) for msg in got]
    assert "fixstream.recorder" in meta  # the metadata survives recovery
    node = _node_reader()
    if node is not None:
        result = _read_with_node(node, out)
        assert result["messages"] == len(got) and result["counts"] == {KEY: len(got)}


def test_seq_extremes_are_not_loss(router: str, tmp_path: Path) -> None:
    """A seq of 2**64 - 1 (invalid: recorded raw) and a valid jump to MAX_SEQ are jumps no transport loss explains:
    counted as such, never added to ``lost`` (which once reached 1.2e21); an ordinary gap of 2 still is."""
    env = {"FIXSTREAM_RECORDER_KEY_EXPR": "fixstream/sensor/**"}
    good = EXAMPLES["Depth"].model_dump(mode="python")
    with recorder(router, tmp_path, instance="seq", **env) as rec:
        for seq in (0, 1, 2):
            rec.send(KEY, restamp(EXAMPLES["Depth"], seq, "test/x"))
        huge = {**good, "header": {**good["header"], "seq": 2**64 - 1, "source": "test/x", "stamp_ns": 5}}
        rec.send_raw(KEY, msgpack.packb(huge), codec.encoding_of(type(EXAMPLES["Depth"])))
        top = EXAMPLES["Depth"].model_copy(update={"header": Header(stamp_ns=6, source="test/x", seq=MAX_SEQ)})
        rec.send(KEY, top)
        rec.send(KEY, restamp(EXAMPLES["Depth"], 0, "test/z"))
        rec.send(KEY, restamp(EXAMPLES["Depth"], 3, "test/z"))  # 1 and 2 lost
        status = rec.wait_status(lambda s: s["counters"]["received"] >= 7)
        rec.terminate()
    # 2 -> 2**64-1 is a jump; 2**64-1 -> MAX_SEQ goes back: a restart as far as anyone can tell
    assert (status["lost"], status["seq_gaps"], status["seq_jumps"], status["seq_resets"]) == (2, 1, 1, 1)
    assert status["counters"]["rejected_by_reason"] == {"out_of_bounds": 1}
    assert status["written"] == 6 and status["rejected_recorded"] == 1


def test_scenario_names_from_the_network_open_nothing_outside(router: str, tmp_path: Path) -> None:
    """Start markers naming /etc/passwd, a relative escape and a symlink that leaves the scenario directory: none is
    read or attached; a plain name inside the directory is, with its map."""
    scen_dir = tmp_path / "scenarios"
    (scen_dir / "maps").mkdir(parents=True)
    doc = (REPO / "scenarios" / "terrain_nav_demo.yaml").read_text()
    (scen_dir / "ok.yaml").write_text(doc.replace("scenarios/maps/", "maps/"))
    shutil.copy(REPO / "scenarios" / "maps" / "terrain_nav_informative.npy", scen_dir / "maps")
    outside = tmp_path / "secret.yaml"
    outside.write_text("name: secret\n")
    (scen_dir / "link.yaml").symlink_to(outside)
    for name in ("/etc/passwd", "../secret", "link", "secret", "ok.yaml", ".hidden"):
        assert find_scenario(name, [scen_dir]) is None, name
    assert find_scenario("ok", [scen_dir]) == scen_dir / "ok.yaml"
    name_of_ok = find_scenario("terrain_nav_demo", [scen_dir])  # looked up by its name: field
    assert name_of_ok == scen_dir / "ok.yaml"

    env = {"FIXSTREAM_RECORDER_SCENARIOS_DIR": str(scen_dir)}
    with recorder(router, tmp_path, instance="conf", **env) as rec:
        for i, name in enumerate(["/etc/passwd", "../secret", "link", "ok"]):
            marker = ScenarioMarker(
                header=Header(stamp_ns=0, source="player/t", seq=i), event="start", scenario=name, seed=3
            )
            rec.send(keys.scenario("x"), marker)
        status = rec.wait_status(lambda s: sum(s["runs"].values()) == 4)
        rec.terminate()
    (path,) = recording_files(rec.out_dir)
    info = scan(path)
    assert {a.name: a.data for a in info.attachments} == {
        "scenario/ok.yaml": (scen_dir / "ok.yaml").read_bytes(),
        "scenario/maps/terrain_nav_informative.npy": (scen_dir / "maps" / "terrain_nav_informative.npy").read_bytes(),
    }
    runs = [dict(m.metadata) for m in info.metadata if m.name == "fixstream.run"]
    assert [(r["scenario"], r["scenario_file"], r["run_index"]) for r in runs] == [
        ("/etc/passwd", "", "1"),
        ("../secret", "", "1"),
        ("link", "", "1"),
        ("ok", "ok.yaml", "1"),
    ]  # every run is named in the file; only the one inside the directory has a file
    assert status["runs"] == {"/etc/passwd": 1, "../secret": 1, "link": 1, "ok": 1}
    assert "root:" not in path.read_bytes().decode("latin-1")


# ----- @mcap/core, the reader Foxglove uses (skipped with a reason when node or npm is absent) -------------------

_NODE_SCRIPT = r"""
const { McapIndexedReader } = require("@mcap/core");
const fs = require("fs/promises");
const fzstd = require("fzstd");
const lz4 = require("lz4js");
async function main() {
  const fh = await fs.open(process.argv[2], "r");
  const size = (await fh.stat()).size;
  const readable = {
    size: async () => BigInt(size),
    read: async (offset, length) => {
      const buf = new Uint8Array(Number(length));
      await fh.read(buf, 0, Number(length), Number(offset));
      return buf;
    },
  };
  const reader = await McapIndexedReader.Initialize({
    readable,
    decompressHandlers: {
      zstd: (buf, n) => fzstd.decompress(buf, new Uint8Array(Number(n))),
      lz4: (buf, n) => new Uint8Array(lz4.decompress(buf, Number(n))),
    },
  });
  const counts = {};
  let messages = 0;
  for await (const msg of reader.readMessages()) {
    const topic = reader.channelsById.get(msg.channelId).topic;
    counts[topic] = (counts[topic] || 0) + 1;
    messages++;
  }
  const metadata = [];
  for await (const m of reader.readMetadata()) metadata.push(m.name);
  const attachments = [];
  for await (const a of reader.readAttachments()) attachments.push(a.name);
  const schemas = [...reader.schemasById.values()].map((s) => [s.name, s.encoding]);
  console.log(JSON.stringify({ messages, counts, metadata, attachments, schemas }));
  await fh.close();
}
main().catch((e) => { console.error(String(e)); process.exit(1); });
"""


def _node_reader() -> Path | None:
    """A directory with @mcap/core installed (once per machine, ~3 s) and the reader script; None without node."""
    if shutil.which("node") is None or shutil.which("npm") is None:
        return None
    d = Path(tempfile.gettempdir()) / "fixstream-mcap-node"
    if not (d / "node_modules" / "@mcap" / "core").is_dir():
        d.mkdir(exist_ok=True)
        done = subprocess.run(
            ["npm", "install", "--no-audit", "--no-fund", "--silent", "@mcap/core@2", "fzstd", "lz4js"],
            cwd=d,
            capture_output=True,
            text=True,
            timeout=120,
        )
        if done.returncode != 0:
            return None
    (d / "read.js").write_text(_NODE_SCRIPT)
    return d


def _read_with_node(d: Path, path: Path) -> dict[str, object]:
    done = subprocess.run(["node", str(d / "read.js"), str(path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return dict(json.loads(done.stdout))


@pytest.mark.node
def test_recording_opens_in_mcap_core_indexed_reader(router: str, tmp_path: Path) -> None:
    node = _node_reader()
    assert node is not None, "node/npm absent or @mcap/core not installable (FIXSTREAM_NODE_TEST=off leaves this out)"
    sent = [restamp(EXAMPLES["Depth"], i, "test/depth") for i in range(50)]
    with recorder(router, tmp_path, instance="node", FIXSTREAM_RECORDER_KEY_EXPR="fixstream/sensor/**") as rec:
        for msg in sent:
            rec.send(KEY, msg)
        rec.send_raw(KEY, b"\xc1junk", codec.encoding_of(type(EXAMPLES["Depth"])))
        rec.wait_status(lambda s: s["counters"]["received"] >= len(sent) + 1)
        rec.terminate()
    (path,) = recording_files(rec.out_dir)
    result = _read_with_node(node, path)
    assert result["counts"] == {KEY: len(sent), f"fixstream/rejected/{KEY}": 1}
    assert "fixstream.recorder" in result["metadata"]  # type: ignore[operator]
    assert ["fixstream.Depth", "jsonschema"] in result["schemas"]  # type: ignore[operator]
    assert os.path.getsize(path) > 0
