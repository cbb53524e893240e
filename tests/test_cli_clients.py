"""The subscribing clients against real processes: ``fixstream echo`` and ``fixstream status``."""

from __future__ import annotations

import json
import signal
import subprocess
from pathlib import Path

import pytest
import zenoh
from conftest import REPO, fixstream_cmd, service_env, wait_until
from samples import EXAMPLES

from shared import codec
from shared.session import open_session
from shared.settings import ZenohSettings

pytestmark = pytest.mark.e2e


def test_echo_prints_each_message_decoded_and_flags_bad_ones(router: str) -> None:
    echo = subprocess.Popen(
        fixstream_cmd("echo", "fixstream/sensor/**", "--json", "--count", "3", "--timeout", "30", "--connect", router),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    session = open_session(ZenohSettings(mode="client", connect=[router]))
    try:
        # publish only once echo's subscriber is routed to us
        probe = session.declare_publisher("fixstream/sensor/a/depth/d")
        assert wait_until(lambda: probe.matching_status.matching, timeout=20)
        probe.undeclare()
        depth, heading = EXAMPLES["Depth"], EXAMPLES["Heading"]
        for key, msg in [("fixstream/sensor/a/depth/d", depth), ("fixstream/sensor/a/heading/h", heading)]:
            session.put(key, codec.encode(msg), encoding=zenoh.Encoding(codec.encoding_of(type(msg))))
        session.put("fixstream/sensor/a/depth/d", b"\xc1", encoding=zenoh.Encoding(codec.encoding_of(type(depth))))
        out, err = echo.communicate(timeout=30)
    finally:
        session.close()
    assert echo.returncode == 0, err
    lines = [json.loads(line) for line in out.splitlines()]
    assert len(lines) == 3
    assert lines[0]["schema"] == "Depth" and lines[0]["message"] == depth.model_dump(mode="json")
    assert lines[1]["schema"] == "Heading" and lines[1]["message"]["heading_rad"] == heading.heading_rad
    assert lines[2]["error"] == "bad_msgpack"


def test_status_lists_every_live_service(router: str, tmp_path: Path) -> None:
    env = service_env(router, FIXSTREAM_RECORDER_INSTANCE="st", FIXSTREAM_RECORDER_OUT_DIR=str(tmp_path))
    rec = subprocess.Popen(fixstream_cmd("run", "recorder"), env=env, cwd=REPO, text=True)
    try:
        session = open_session(ZenohSettings(mode="client", connect=[router]))
        assert wait_until(lambda: len(list(session.liveliness().get("fixstream/alive/recorder/st", timeout=0.5))) == 1)
        session.close()
        done = subprocess.run(
            fixstream_cmd("status", "--json", "--connect", router), cwd=REPO, capture_output=True, text=True, timeout=30
        )
        assert done.returncode == 0, done.stderr
        replies = [json.loads(line) for line in done.stdout.splitlines()]
        assert [(r["service"], r["instance"]) for r in replies] == [("recorder", "st")]
        assert replies[0]["config"]["out_dir"] == str(tmp_path)
        # a live service that does not answer (stopped: SIGSTOP) is named on stderr; stdout stays JSON lines only
        rec.send_signal(signal.SIGSTOP)
        try:
            done = subprocess.run(
                fixstream_cmd("status", "--json", "--timeout", "1", "--connect", router),
                cwd=REPO,
                capture_output=True,
                text=True,
                timeout=30,
            )
        finally:
            rec.send_signal(signal.SIGCONT)
        assert done.returncode == 3, done.stderr  # no answer at all
        assert all(json.loads(line) for line in done.stdout.splitlines() if not line.startswith("no service"))
        assert "alive but no answer within 1 s: recorder/st" in done.stderr, done.stderr
    finally:
        rec.terminate()
        rec.wait(timeout=30)
    # with nothing alive the command says so and exits with the timeout status (3)
    done = subprocess.run(
        fixstream_cmd("status", "--timeout", "0.5", "--connect", router), cwd=REPO, capture_output=True, text=True
    )
    assert done.returncode == 3 and "no service answered" in done.stdout
