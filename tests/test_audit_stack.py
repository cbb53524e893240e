"""Findings of a new-user audit about the stack runner, the recorder and session start-up, each checked where it
happened: real processes, a real router, real sockets.

* a router port asked for is never replaced in silence; TIME_WAIT does not make a port busy; bad ports are one line
  and exit 2 (audit 5, 6);
* Ctrl-C / SIGTERM while waiting for the router stop the process at once, 130 / 143 (audit 3);
* an endpoint Zenoh cannot parse is called invalid, not unreachable (audit 13);
* a recorder that cannot write backs off instead of trying a new file per message, exits 1, and ``fixstream up``
  then fails; ``up`` lists only what its own recorder wrote (audit 1, 4);
* the services' configuration in the recording waits for every live service (audit 8);
* the recorder's final diagnostic counts reach the recording (audit 15).
"""

from __future__ import annotations

import json
import logging
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, cast

import pytest
import yaml
import zenoh
from conftest import REPO, fixstream_cmd
from mcap.reader import make_reader
from recorder_support import by_topic, recorder, records_of, restamp
from samples import EXAMPLES
from test_scenario_files import nav_scenario

from schemas import Depth, Diagnostic, Header
from services.recorder.run_context import ANSWERED_KEY, services_metadata
from services.recorder.service import RecorderService
from services.recorder.settings import RecorderSettings
from shared import codec, keys, local_stack
from shared.errors import ConnectError
from shared.mcap_io import recording_files
from shared.session import open_session, port_free
from shared.settings import ZenohSettings
from shared.status import collect_statuses
from tools.stack import ComposeError, load_compose, plan_stack
from tools.stack.plan import DEFAULT_ROUTER_PORT

UNWRITABLE = Path("/sys/kernel")  # a directory nobody, root included, can create files in


def _unwritable() -> bool:
    try:
        fd = os.open(UNWRITABLE / "fixstream-probe.mcap", os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except OSError:
        return UNWRITABLE.is_dir()
    os.close(fd)
    return False


needs_unwritable = pytest.mark.skipif(not _unwritable(), reason=f"{UNWRITABLE} is writable here")

ROUTER_ONLY = """
services:
  router:
    image: eclipse/zenoh:1.10.2
    command: ["--listen", "tcp/0.0.0.0:7447"]
"""


# --- router port: asked for is kept or refused, never replaced; TIME_WAIT is not busy (audit 5, 6) ----------------


def _time_wait_port() -> int:
    """A port whose only trace is a connection in TIME_WAIT (the side that closed first keeps it), left by a
    listener with SO_REUSEADDR, as the Zenoh router's (its accepted connections inherit it)."""
    listener = socket.socket()
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    listener.bind(("127.0.0.1", 0))
    listener.listen()
    port = int(listener.getsockname()[1])
    client = socket.create_connection(("127.0.0.1", port))
    accepted, _ = listener.accept()
    accepted.close()  # the server side closes first: its end (127.0.0.1:port) goes to TIME_WAIT
    time.sleep(0.05)
    client.close()
    listener.close()
    time.sleep(0.05)
    return port


def test_a_port_in_time_wait_is_free_for_a_router() -> None:
    port = _time_wait_port()
    plain = socket.socket()
    try:
        with pytest.raises(OSError):  # what the probe did without SO_REUSEADDR: "busy"
            plain.bind(("127.0.0.1", port))
    finally:
        plain.close()
    assert port_free(port)
    with socket.socket() as listener:  # and a listener really binds it, as the router does
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", port))
        listener.listen()
        assert not port_free(port)


def test_a_busy_router_port_asked_for_is_an_error_not_a_fallback(tmp_path: Path) -> None:
    (tmp_path / "compose.yaml").write_text(ROUTER_ONLY)
    with socket.socket() as blocker:
        blocker.bind(("127.0.0.1", 0))
        blocker.listen()
        busy = int(blocker.getsockname()[1])
        project = load_compose(tmp_path / "compose.yaml", environ={})
        with pytest.raises(ComposeError, match=f"--router-port {busy}: the port is in use"):
            plan_stack(project, ["router"], create_dirs=False, router_port=busy)
        by_variable = load_compose(tmp_path / "compose.yaml", environ={"FIXSTREAM_ROUTER_PORT": str(busy)})
        with pytest.raises(ComposeError, match=f"FIXSTREAM_ROUTER_PORT {busy}: the port is in use"):
            plan_stack(by_variable, ["router"], create_dirs=False)
        assert plan_stack(project, ["router"], create_dirs=False, router_port=0).endpoint != f"tcp/127.0.0.1:{busy}"


def test_the_default_port_of_a_stack_announced_but_not_listening_yet_is_left_to_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two stacks started at once: the first has announced 7447 and is starting its router; the second must not
    plan the same port (its router would fail to bind, and its readiness probe would see the other's router)."""
    monkeypatch.setenv("FIXSTREAM_STATE_DIR", str(tmp_path / "state"))
    (tmp_path / "compose.yaml").write_text(ROUTER_ONLY)
    project = load_compose(tmp_path / "compose.yaml", environ={})
    announcement = local_stack.announce(f"tcp/127.0.0.1:{DEFAULT_ROUTER_PORT}", "other/compose.yaml")
    try:
        assert plan_stack(project, ["router"], create_dirs=False).endpoint != f"tcp/127.0.0.1:{DEFAULT_ROUTER_PORT}"
    finally:
        local_stack.withdraw(announcement)


@pytest.mark.parametrize(
    ("args", "env", "expected"),
    [
        (["--router-port", "99999"], {}, "--router-port 99999 is not a port number"),
        ([], {"FIXSTREAM_ROUTER_PORT": "abc"}, "$FIXSTREAM_ROUTER_PORT='abc' is not a port number"),
    ],
)
def test_a_bad_router_port_is_one_line_and_exit_2(
    tmp_path: Path, args: list[str], env: dict[str, str], expected: str
) -> None:
    (tmp_path / "compose.yaml").write_text(ROUTER_ONLY)
    done = subprocess.run(
        fixstream_cmd("up", "--dry-run", *args),
        cwd=tmp_path,
        env={**os.environ, **env},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    (line,) = done.stderr.splitlines()
    assert line.startswith(f"fixstream up: {expected} (1-65535"), line
    assert "Traceback" not in done.stdout + done.stderr


# --- start-up: signals while waiting for the router; an invalid endpoint (audit 3, 13) ------------------------------


@pytest.mark.parametrize(
    ("command", "sig", "code"),
    [
        (["echo", "--connect", "tcp/127.0.0.1:1", "--connect-timeout", "-1"], signal.SIGINT, 130),
        (["echo", "--connect", "tcp/127.0.0.1:1", "--connect-timeout", "20"], signal.SIGTERM, 143),
        (["run", "lbl_nav"], signal.SIGINT, 130),
    ],
)
def test_a_signal_while_waiting_for_the_router_stops_at_once(command: list[str], sig: int, code: int) -> None:
    env = {**os.environ, "FIXSTREAM_ZENOH_CONNECT": "tcp/127.0.0.1:1", "FIXSTREAM_ZENOH_CONNECT_TIMEOUT_S": "-1"}
    proc = subprocess.Popen(
        fixstream_cmd(*command), cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        time.sleep(2.5)  # imports done, blocked in the session's open
        assert proc.poll() is None, proc.communicate()
        t0 = time.monotonic()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=10)
        assert proc.returncode == code, err
        assert time.monotonic() - t0 < 2.0
        assert "Traceback" not in err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_an_invalid_endpoint_is_called_invalid() -> None:
    with pytest.raises(ConnectError, match="invalid Zenoh connect endpoint in garbage"):
        open_session(ZenohSettings(mode="client", connect=["garbage"]))
    done = subprocess.run(
        fixstream_cmd("status"),
        cwd=REPO,
        env={**os.environ, "FIXSTREAM_ZENOH_CONNECT": "garbage"},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2
    (line,) = done.stderr.splitlines()
    assert "invalid Zenoh connect endpoint in garbage" in line and "reachable" not in line, line


# --- a recorder that cannot write (audit 1) ------------------------------------------------------------------------


@needs_unwritable
def test_a_recorder_that_cannot_write_backs_off_instead_of_a_file_per_message(caplog: pytest.LogCaptureFixture) -> None:
    rec = RecorderService(RecorderSettings(out_dir=UNWRITABLE, instance="nowrite"))
    depth = EXAMPLES["Depth"]
    encoding = codec.encoding_of(Depth)
    n = 500
    with caplog.at_level(logging.ERROR, logger="fixstream.recorder"):
        for i in range(n):
            rec.on_sample("fixstream/sensor/a/depth/d", codec.encode(restamp(depth, i, "t/d")), encoding)
    assert rec.write_errors == 1  # one attempt, then the pause (it was one failed file name per message)
    assert rec.unwritten == n - 1
    assert len([r for r in caplog.records if "failed" in r.getMessage()]) == 1
    status = rec.status_extra()
    assert status["write_failing"] is True and status["unwritten"] == n - 1
    assert "Permission denied" in status["last_write_error"]


UP_COMPOSE = """
services:
  router:
    image: eclipse/zenoh:1.10.2
    command: ["--listen", "tcp/0.0.0.0:7447"]
  recorder:
    image: fixstream:latest
    command: ["fixstream", "run", "recorder"]
    environment:
      FIXSTREAM_ZENOH_CONNECT: tcp/router:7447
      FIXSTREAM_RECORDER_INSTANCE: up1
      FIXSTREAM_RECORDER_OUT_DIR: /data/rec
    volumes: ["${FIXSTREAM_RECORDINGS:-./rec}:/data/rec"]
    depends_on: [router]
  player:
    image: fixstream:latest
    command: ["fixstream", "play", "/scen/s.yaml", "--rate", "0", "--wait-for", "recorder/up1"]
    environment:
      FIXSTREAM_ZENOH_CONNECT: tcp/router:7447
    volumes: ["./scen:/scen:ro"]
    depends_on: [recorder]
    labels: {fixstream.role: driver}
"""


def _up(root: Path, *args: str) -> subprocess.CompletedProcess[str]:
    (root / "compose.yaml").write_text(UP_COMPOSE)
    (root / "scen").mkdir(exist_ok=True)
    (root / "scen" / "s.yaml").write_text(yaml.safe_dump(nav_scenario("s", duration_s=2.0), sort_keys=False))
    return subprocess.run(
        fixstream_cmd("up", "--no-color", "--router-port", "0", "--drain", "0.3", *args),
        cwd=root,
        env=os.environ.copy(),
        capture_output=True,
        text=True,
        timeout=120,
    )


@needs_unwritable
def test_up_fails_when_its_recorder_could_write_nothing(tmp_path: Path) -> None:
    done = _up(tmp_path, "--recordings", str(UNWRITABLE))
    out = done.stdout + done.stderr
    assert done.returncode == 1, out
    assert "[up] recorder exited with code 1" in out and "[up] recorder: no MCAP file written" in out
    assert out.count("writing ") <= 5, out  # a few backed-off attempts, not one per message


def test_up_lists_only_the_files_its_own_recorder_wrote(tmp_path: Path) -> None:
    """A second stack writing into the same folder during the run (here: a file that appears with a fresh time)
    is not this run's recording."""
    rec = tmp_path / "rec"
    rec.mkdir()
    foreign = rec / "fixstream_other_stack_000.mcap"
    foreign.write_bytes(b"not ours")
    future = time.time() + 60
    os.utime(foreign, (future, future))
    done = _up(tmp_path)
    out = done.stdout
    assert done.returncode == 0, out + done.stderr
    listed = [line.split("recording: ", 1)[1].split(" (")[0] for line in out.splitlines() if "recording: " in line]
    assert [Path(p) for p in listed] == [f for f in recording_files(rec) if f != foreign], out
    assert len(listed) == 1


# --- the services' configuration waits for every live service (audit 8) -------------------------------------------


def test_the_status_query_is_repeated_until_every_live_service_answered(router: str) -> None:
    session = open_session(ZenohSettings(mode="client", connect=[router]))
    declared: list[Any] = []
    asked: dict[str, int] = {}

    def answer(instance: str, skip_first: bool) -> Any:
        def on_query(query: zenoh.Query) -> None:
            asked[instance] = asked.get(instance, 0) + 1
            if skip_first and asked[instance] == 1:
                return  # busy: the first query goes unanswered (as a service behind on a loaded machine)
            doc = {"service": "fake", "instance": instance, "config": {"i": instance}, "version": "t"}
            query.reply(keys.status("fake", instance), json.dumps(doc).encode())

        return on_query

    try:
        for instance, slow in (("a", False), ("b", True), ("c", False)):
            declared.append(session.declare_queryable(keys.status("fake", instance), answer(instance, slow)))
            declared.append(session.liveliness().declare_token(keys.alive("fake", instance)))
        declared.append(session.liveliness().declare_token(keys.alive("fake", "mute")))  # alive, no status
        client = open_session(ZenohSettings(mode="client", connect=[router]))
        try:
            t0 = time.monotonic()
            statuses, alive = collect_statuses(client, 0.5)
            elapsed = time.monotonic() - t0
        finally:
            client.close()
    finally:
        for d in declared:
            d.undeclare()
        session.close()
    assert sorted(s["instance"] for s in statuses) == ["a", "b", "c"]  # b answered the second query
    assert alive == ["fake/a", "fake/b", "fake/c", "fake/mute"]
    assert elapsed < 3 * 2 * 0.5 + 2.0  # bounded: three rounds of (tokens + status) at most
    meta = services_metadata(statuses, alive)
    assert json.loads(meta[ANSWERED_KEY]) == {"answered": 3, "alive": 4, "missing": ["fake/mute"]}
    assert json.loads(meta["fake/b"])["config"] == {"i": "b"}


# --- the recorder's last diagnostic counts are in the recording (audit 15) ------------------------------------------


def test_the_recorders_final_diagnostic_counts_reach_the_recording(router: str, tmp_path: Path) -> None:
    key = "fixstream/sensor/a/depth/d"
    bad = b"\xc1 not msgpack"
    encoding = codec.encoding_of(Depth)
    # diagnostics at most once an hour: the only one due is the final one, at the close (what --rate 0 leaves)
    with recorder(router, tmp_path, instance="diag1", FIXSTREAM_RECORDER_DIAG_INTERVAL_S="3600") as rec:
        for _ in range(5):
            rec.send_raw(key, bad, encoding)
        rec.wait_status(lambda s: s["counters"]["rejected"] == 5)
        rec.terminate()
    own = keys.diag("recorder", "diag1")
    topics = by_topic([r for r in records_of(recording_files(rec.out_dir)) if r.topic == own])
    diags = [d for d in topics[own] if isinstance(d, Diagnostic)]
    assert [(d.reason, d.count) for d in diags] == [("bad_msgpack", 5)], [(d.header, d.detail) for d in diags]


def test_threads_left_by_an_interrupted_open_are_daemons() -> None:
    """The open that a signal abandons keeps running in Rust on its thread; it must never hold the process."""
    code = (
        "import os, signal, threading, time\n"
        "from shared.session import open_session\n"
        "from shared.settings import ZenohSettings\n"
        "threading.Timer(0.5, lambda: os.kill(os.getpid(), signal.SIGTERM)).start()\n"
        "open_session(ZenohSettings(mode='client', connect=['tcp/127.0.0.1:1'], connect_timeout_s=-1))\n"
    )
    t0 = time.monotonic()
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=30)
    assert done.returncode == 143, done.stderr
    assert time.monotonic() - t0 < 10


def test_a_caller_that_keeps_its_signal_handlers_sees_them_run_during_the_open() -> None:
    """The stack runner's own handler (stop the processes first) runs while the open waits, and the open goes on."""
    seen: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, _frame: seen.append(signum))
    try:
        timer = threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGINT))
        timer.start()
        t0 = time.monotonic()
        with pytest.raises(ConnectError, match="no Zenoh router reachable"):
            settings = ZenohSettings(mode="client", connect=["tcp/127.0.0.1:1"], connect_timeout_s=1.5)
            open_session(settings, take_signals=False)
        timer.join()
        assert seen == [signal.SIGINT]
        assert time.monotonic() - t0 >= 1.4  # the open was not cut short
    finally:
        signal.signal(signal.SIGINT, previous)


def test_the_services_are_asked_before_the_slow_scenario_look_up(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The look-up of a start marker's scenario took 1.7-3 s on a first run; at --rate 0 the services were stopped
    by the time the status query went out after it (1 to 4 of 9 answered). The query goes out first."""
    import services.recorder.service as recorder_module
    from schemas import ScenarioMarker

    rec = RecorderService(RecorderSettings(out_dir=tmp_path, instance="order"))
    rec._control = cast(Any, object())  # a session stand-in: the query thread's calls fail and are suppressed
    order: list[str] = []
    original = recorder_module.run_context

    def slow_lookup(*args: Any, **kwargs: Any) -> Any:
        order.append("asked" if rec._status_thread is not None else "not asked")
        return original(*args, **kwargs)

    monkeypatch.setattr(recorder_module, "run_context", slow_lookup)
    marker = ScenarioMarker(
        header=Header(stamp_ns=1, source="player/default", seq=0), event="start", scenario="nowhere", seed=1
    )
    rec.on_sample(keys.scenario("nowhere"), codec.encode(marker), codec.encoding_of(ScenarioMarker))
    rec._open_looked_up(wait=True)  # the look-up runs on a worker thread (next test)
    assert order == ["asked"]
    rec.on_stop()


def test_a_slow_scenario_look_up_does_not_hold_the_recording(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A start marker's scenario look-up takes seconds on a first run (the simulators' imports: 1.7 s for the demo
    on an idle machine, 7 s with two stacks at once), during which the recorder used to record nothing while Zenoh
    held the whole stack back. It runs on a worker thread now: the samples after the marker are written while it
    is still blocked, and its metadata and attachments reach the file once it is done."""
    import services.recorder.service as recorder_module
    from schemas import ScenarioMarker

    rec = RecorderService(RecorderSettings(out_dir=tmp_path, instance="slow", scenarios_dir=REPO / "scenarios"))
    rec._control = cast(Any, object())  # a session stand-in: the status query's calls fail and are suppressed
    release = threading.Event()
    original = recorder_module.run_context

    def blocked_lookup(*args: Any, **kwargs: Any) -> Any:
        assert release.wait(20.0)
        return original(*args, **kwargs)

    monkeypatch.setattr(recorder_module, "run_context", blocked_lookup)
    marker = ScenarioMarker(
        header=Header(stamp_ns=1, source="player/default", seq=0), event="start", scenario="demo", seed=1
    )
    t0 = time.monotonic()
    rec.on_sample(keys.scenario("demo"), codec.encode(marker), codec.encoding_of(ScenarioMarker))
    depth, encoding = EXAMPLES["Depth"], codec.encoding_of(Depth)
    for i in range(100):
        rec.on_sample("fixstream/sensor/a/depth/d", codec.encode(restamp(depth, i, "player/default")), encoding)
    rec._housekeeping()
    assert time.monotonic() - t0 < 5.0 and rec.counters.accepted == 101 and rec.current_run is None
    release.set()
    rec._open_looked_up(wait=True)
    assert rec.current_run is not None and rec.current_run.scenario_path == REPO / "scenarios" / "demo.yaml"
    rec.on_stop()
    (path,) = recording_files(tmp_path)
    with path.open("rb") as f:
        reader = make_reader(f)
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        attachments = [a.name for a in reader.iter_attachments()]
    assert metadata["fixstream.run"]["scenario"] == "demo" and "scenario/demo.yaml" in attachments


def test_up_chooses_its_port_under_the_stack_lock(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two stacks started at once: each chooses its router port and announces it while holding this user's stack
    lock, so the second sees the first's announcement. Here the test is the first stack: while it holds the lock,
    ``fixstream up`` chooses nothing; the test announces 7447 and lets go; ``up`` then takes another port and runs.
    (Without the lock both found 7447 free within about 100 ms, and the second router could not bind.)"""
    state = tmp_path / "state"
    monkeypatch.setenv("FIXSTREAM_STATE_DIR", str(state))
    (tmp_path / "compose.yaml").write_text(UP_COMPOSE)
    (tmp_path / "scen").mkdir()
    (tmp_path / "scen" / "s.yaml").write_text(yaml.safe_dump(nav_scenario("s", duration_s=2.0), sort_keys=False))
    lines: list[str] = []
    cmd = fixstream_cmd("up", "--no-color", "--drain", "0.3", "--recordings", str(tmp_path / "rec"))
    with local_stack.exclusive():
        proc = subprocess.Popen(cmd, cwd=tmp_path, env=os.environ.copy(), stdout=subprocess.PIPE, text=True)
        assert proc.stdout is not None
        reader = threading.Thread(target=lambda: lines.extend(proc.stdout or ()), daemon=True)
        reader.start()
        time.sleep(3.0)  # long enough for up to start and plan (about 1 s here)
        assert proc.poll() is None and not any("router on" in line for line in lines), lines
        announcement = local_stack.announce(f"tcp/127.0.0.1:{DEFAULT_ROUTER_PORT}", "first/compose.yaml")
    try:
        rc = proc.wait(timeout=120)
        reader.join(timeout=10)
    finally:
        local_stack.withdraw(announcement)
        if proc.poll() is None:
            proc.kill()
    out = "".join(lines)
    assert rc == 0, out[-3000:]
    port = int(re.search(r"router on tcp/127\.0\.0\.1:(\d+)", out).group(1))  # type: ignore[union-attr]
    assert port != DEFAULT_ROUTER_PORT, out[-3000:]
