"""``fixstream play`` options over a real router (issue 17, items 6 and 7).

A small recording, written with the ``mcap`` library itself (not fixstream's recorder), holds what a stack's
recording holds: the player's keys (a scenario marker, a sensor, truth, the AUV group's uplink), the services'
answers (fixes, diagnostics) and a Foxglove scene channel. Replayed:

* by default, exactly the player's records come back on Zenoh, byte for byte and in file order; the fixes and
  diagnostics stay out (they would sit beside the live services' own), the Foxglove channel is left out without a
  warning line, and the summary says what was left out;
* ``--all --exclude fixstream/diag/**`` and ``--keys fixstream/fix/**`` select what they name;
* the progress line is drawn on stderr when stderr is a terminal (a pty here), or with ``--progress``, never
  otherwise, and reaches N/N with N the records the selection replays.

``--wait-timeout`` bounds the wait for services of a scenario file (item 7: the file's ``wait_timeout_s`` no longer
wins over the command line) and of a recording; a scenario's progress line counts the share of its duration.
"""

from __future__ import annotations

import os
import pty
import re
import subprocess
import threading
import time
from pathlib import Path

import pytest
import yaml
from cli_support import TestPublisher, finish, start
from conftest import REPO, fixstream_cmd, wait_until
from mcap.writer import Writer
from samples import EXAMPLES

from schemas import Header, Message
from services.player.selection import PLAYER_KEYS, KeySelection
from shared import codec
from shared.session import open_session
from shared.settings import ZenohSettings
from tools.stack.pki import ROUTER_ACL

pytestmark = pytest.mark.e2e

T0_NS = 1_700_000_000_000_000_000
MS = 1_000_000
PLAYER = {
    "fixstream/scenario/rec": "ScenarioMarker",
    "fixstream/sensor/p1/depth/d0": "Depth",
    "fixstream/truth/p1": "Truth",
    "fixstream/group/g1/uplink/base/nodes": "BeaconTable",
}
ANSWERS = {"fixstream/fix/lbl/p1": "Fix", "fixstream/diag/lbl_nav/default": "Diagnostic"}
FOXGLOVE_TOPIC = "/foxglove/scene/fix/lbl/p1"


def _stamped(name: str, seq: int) -> Message:
    msg = EXAMPLES[name]
    header = Header(stamp_ns=seq * 100 * MS, frame_id="local_enu", source="test/rec", seq=seq)
    return msg.model_copy(update={"header": header})


def _write_recording(path: Path, rounds: int = 5) -> list[tuple[str, Message]]:
    """Every key once per round, 10 ms of log time apart, plus a Foxglove channel; returns (key, msg) in file
    order."""
    written: list[tuple[str, Message]] = []
    with path.open("wb") as f:
        w = Writer(f)
        w.start(profile="", library="test")
        channels = {}
        for key, name in {**PLAYER, **ANSWERS}.items():
            schema = w.register_schema(name=f"fixstream.{name}", encoding="jsonschema", data=b"{}")
            channels[key] = w.register_channel(topic=key, message_encoding="json", schema_id=schema)
        scene = w.register_schema(name="foxglove.SceneUpdate", encoding="protobuf", data=b"\x0a\x00")
        scene_ch = w.register_channel(topic=FOXGLOVE_TOPIC, message_encoding="protobuf", schema_id=scene)
        t = T0_NS
        for i in range(rounds):
            for key, name in {**PLAYER, **ANSWERS}.items():
                msg = _stamped(name, i)
                w.add_message(channels[key], log_time=t, data=msg.model_dump_json().encode(), publish_time=t)
                written.append((key, msg))
                t += 10 * MS
            w.add_message(scene_ch, log_time=t, data=b"\x0a\x00", publish_time=t)
        w.finish()
    return written


class Collector:
    """Samples on ``fixstream/**`` of a router, in arrival order."""

    def __init__(self, router: str) -> None:
        self.session = open_session(ZenohSettings(mode="client", connect=[router]))
        self.samples: list[tuple[str, bytes]] = []
        self._lock = threading.Lock()
        self._sub = self.session.declare_subscriber("fixstream/**", self._on)

    def _on(self, s: object) -> None:
        with self._lock:
            self.samples.append((str(s.key_expr), s.payload.to_bytes()))  # type: ignore[attr-defined]

    def take(self, n: int, timeout: float = 10.0) -> list[tuple[str, bytes]]:
        assert wait_until(lambda: len(self.samples) >= n, timeout=timeout), (n, len(self.samples))
        time.sleep(0.3)  # nothing more may come
        with self._lock:
            out, self.samples = list(self.samples), []
        return out

    def close(self) -> None:
        self._sub.undeclare()
        self.session.close()


def _expected(written: list[tuple[str, Message]], select: KeySelection) -> list[tuple[str, bytes]]:
    return [(k, codec.encode(m)) for k, m in written if select(k)]


def _replay_on_a_pty(router: str, path: Path) -> tuple[int, str, str]:
    """Replay with stderr on a terminal (a pty), stdout on a pipe; returns (exit status, stdout, terminal text)."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        fixstream_cmd("play", str(path), "--rate", "0", "--linger", "0.3", "--connect", router),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=slave,
        text=True,
    )
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 4096)
        except OSError:  # EIO: the process closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    os.close(master)
    out, _ = proc.communicate(timeout=60)
    return proc.returncode, out, b"".join(chunks).decode(errors="replace")


def test_replay_selects_keys_and_leaves_foxglove_channels_out_quietly(router: str, tmp_path: Path) -> None:
    path = tmp_path / "rec.mcap"
    written = _write_recording(path)
    n_player = sum(1 for k, _ in written if k in PLAYER)
    collector = Collector(router)
    probe = TestPublisher(router)
    try:
        probe.wait_for_subscriber("fixstream/x")
        # 1. the default, with stderr on a terminal: the player's keys only, and a progress line
        code, out, tty = _replay_on_a_pty(router, path)
        assert code == 0, tty
        assert collector.take(n_player) == _expected(written, KeySelection())
        assert f"replayed {n_player} records on 4 keys" in out and "(0 skipped)" in out
        assert "left out: 10 on keys not replayed" in out and "5 on Foxglove/foreign channels" in out
        assert f"\r{'replay rec.mcap'}: {n_player}/{n_player} messages (100 %)" in tty
        assert "foxglove" not in tty.lower() and "WARNING" not in tty  # no line per Foxglove record
        # 2. every key but the diagnostics; stderr a pipe: no progress line
        code, out, err = finish(
            start("play", str(path), "--rate", "0", "--all", "--exclude", "fixstream/diag/**", "--connect", router)
        )
        assert code == 0, err
        everything_but_diag = KeySelection(None, ("fixstream/diag/**",))
        assert collector.take(len(_expected(written, everything_but_diag))) == _expected(written, everything_but_diag)
        assert "\r" not in err and "messages (" not in err
        # 3. only the fixes, progress asked for on a pipe
        code, out, err = finish(
            start("play", str(path), "--rate", "0", "--keys", "fixstream/fix/**", "--progress", "--connect", router)
        )
        assert code == 0, err
        assert collector.take(5) == [(k, codec.encode(m)) for k, m in written if k == "fixstream/fix/lbl/p1"]
        # (text mode reads the line's carriage returns as line ends)
        assert re.search(r"^replay rec\.mcap: 5/5 messages \(100 %\), 0\.\d s of data", err, re.MULTILINE), err
    finally:
        probe.close()
        collector.close()


def test_default_replay_keys_are_what_the_secure_router_lets_the_player_write() -> None:
    """The replay's default set and the player's write permission in the router's access control are one list."""
    acl = ROUTER_ACL.read_text()
    rule = acl[acl.index('id: "player_feeds"') :]
    rule = rule[rule.index("key_exprs: [") + len("key_exprs: [") :]
    rule = rule[: rule.index("]")]
    allowed = {k for k in re.findall(r'"([^"]+)"', rule) if not k.startswith("fixstream/alive/")}
    assert allowed == set(PLAYER_KEYS)
    select = KeySelection()
    assert select("fixstream/rejected/fixstream/sensor/p1/depth/d0")  # a kept rejected payload: its original key
    assert not select("fixstream/rejected/fixstream/fix/lbl/p1")
    assert not select(FOXGLOVE_TOPIC)


def test_wait_timeout_on_the_command_line_wins_over_the_scenario_file(router: str, tmp_path: Path) -> None:
    doc = yaml.safe_load((REPO / "scenarios" / "demo.yaml").read_text())
    doc["simulators"] = [sim for sim in doc["simulators"] if sim["kind"] == "nav_platform"]  # quick to load
    doc.update(name="waits", wait_for=["nobody/here"], wait_timeout_s=30.0, estimators=[])
    slow = tmp_path / "waits.yaml"
    slow.write_text(yaml.safe_dump(doc))
    doc.update(name="waits_briefly", wait_timeout_s=1.0)
    brief = tmp_path / "waits_briefly.yaml"
    brief.write_text(yaml.safe_dump(doc))
    doc.update(name="short", wait_for=[], duration_s=1.0)
    short = tmp_path / "short.yaml"
    short.write_text(yaml.safe_dump(doc))
    mcap = tmp_path / "rec.mcap"
    _write_recording(mcap, rounds=1)
    t0 = time.monotonic()
    runs = {
        "flag": start("play", str(slow), "--wait-timeout", "0.5", "--connect", router),
        "file": start("play", str(brief), "--connect", router),
        "mcap": start("play", str(mcap), "--wait-for", "nobody", "--wait-timeout", "0.5", "--connect", router),
        # meanwhile: a scenario's progress line, by the share of its duration played
        "short": start("play", str(short), "--rate", "0", "--progress", "--linger", "0", "--connect", router),
    }
    results = {name: finish(proc) for name, proc in runs.items()}
    elapsed = time.monotonic() - t0
    assert elapsed < 20.0, elapsed  # not the file's 30 s
    code, _, err = results["flag"]
    assert code == 3 and err.strip().endswith("no live token on fixstream/alive/nobody/here after 0.5 s"), err
    code, _, err = results["file"]
    assert code == 3 and err.strip().endswith("after 1 s"), err  # no flag: the file's value
    code, _, err = results["mcap"]
    assert code == 3 and err.strip().endswith("no live token on fixstream/alive/nobody/* after 0.5 s"), err
    code, out, err = results["short"]
    assert code == 0, err
    n = int(re.search(r"published (\d+) messages", out).group(1))  # type: ignore[union-attr]
    assert re.search(rf"^play short: {n} messages \(100 %\), 1\.0/1\.0 s of data", err, re.MULTILINE), err
    # key options are for recordings only
    code, _, err = finish(start("play", str(slow), "--all", "--connect", router))
    assert code == 2 and "select keys of a recording" in err
