"""Clients meet the stack as a user does: several services at once, ``fixstream up`` in one process and the
clients in another with no flags, a service that starts before its router, a router that restarts, bad starts.

Everything here runs real processes over real loopback sockets (issue 13)."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from conftest import REPO, fixstream_cmd, service_env, wait_until
from samples import EXAMPLES

from schemas import Depth, Header
from shared import codec, keys, local_stack
from shared.mcap_io import decode_record, iter_records, recording_files
from shared.session import free_tcp_port, open_session
from shared.settings import ZenohSettings
from tools.stack.plan import DEFAULT_ROUTER_PORT

pytestmark = pytest.mark.e2e


def _client_env(**extra: str) -> dict[str, str]:
    """A user's shell: no Zenoh settings at all (only the tests' own state directory)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_") or k == "FIXSTREAM_STATE_DIR"}
    env.update(extra)
    return env


def _statuses(*args: str, env: dict[str, str] | None = None) -> list[tuple[str, str]]:
    done = subprocess.run(
        fixstream_cmd("status", "--json", *args),
        cwd=REPO,
        env=env if env is not None else _client_env(),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return [(r["service"], r["instance"]) for r in map(json.loads, done.stdout.splitlines())]


@contextlib.contextmanager
def _services(router: str, specs: list[tuple[str, dict[str, str]]]) -> Iterator[list[subprocess.Popen[str]]]:
    procs = [
        subprocess.Popen(fixstream_cmd("run", name), env=service_env(router, **env), cwd=REPO, text=True)
        for name, env in specs
    ]
    try:
        yield procs
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()


def _alive_count(session: zenoh.Session, key_expr: str = "fixstream/alive/**") -> int:
    return len(list(session.liveliness().get(key_expr, timeout=0.5)))


# --- status answers for every service -------------------------------------------------------------------------------


def test_status_lists_every_live_service_every_time(router: str, tmp_path: Path) -> None:
    """Five services on one router: every call lists all five (the consolidation bug showed one, a different
    one each call)."""
    specs = [
        ("recorder", {"FIXSTREAM_RECORDER_INSTANCE": "st", "FIXSTREAM_RECORDER_OUT_DIR": str(tmp_path)}),
        ("lbl_nav", {"FIXSTREAM_LBL_NAV_INSTANCE": "a"}),
        ("lbl_nav", {"FIXSTREAM_LBL_NAV_INSTANCE": "b"}),
        ("coordinator", {"FIXSTREAM_COORDINATOR_INSTANCE": "g1"}),
        ("rd_nav", {"FIXSTREAM_RD_NAV_INSTANCE": "auv9"}),
    ]
    expected = sorted(
        [("recorder", "st"), ("lbl_nav", "a"), ("lbl_nav", "b"), ("coordinator", "g1"), ("rd_nav", "auv9")]
    )
    with _services(router, specs):
        watch = open_session(ZenohSettings(mode="client", connect=[router]))
        try:
            assert wait_until(lambda: _alive_count(watch) == len(specs), timeout=60)
        finally:
            watch.close()
        for _ in range(3):
            assert _statuses("--connect", router) == expected


# --- fixstream up, then clients with no flags -----------------------------------------------------------------------

COMPOSE = """
services:
  router:
    image: eclipse/zenoh:1.10.2
    command: ["--listen", "tcp/0.0.0.0:7447", "--no-multicast-scouting"]
  recorder:
    image: fixstream:latest
    command: ["fixstream", "run", "recorder"]
    environment:
      FIXSTREAM_ZENOH_CONNECT: tcp/router:7447
      FIXSTREAM_RECORDER_INSTANCE: att
      FIXSTREAM_RECORDER_OUT_DIR: /data/rec
    volumes: ["./rec:/data/rec"]
    depends_on: [router]
  lbl_nav-x:
    image: fixstream:latest
    command: ["fixstream", "run", "lbl_nav"]
    environment:
      FIXSTREAM_ZENOH_CONNECT: tcp/router:7447
      FIXSTREAM_LBL_NAV_INSTANCE: x
    depends_on: [router]
"""


class _Up:
    """``fixstream up`` in the background; its console lines collected."""

    def __init__(self, root: Path, env: dict[str, str]) -> None:
        self.proc = subprocess.Popen(
            fixstream_cmd("up", "-f", str(root / "compose.yaml"), "--no-color"),
            cwd=root,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def saw(self, text: str) -> bool:
        return any(text in line for line in list(self.lines))

    def stop(self) -> int:
        self.proc.send_signal(signal.SIGINT)
        rc = self.proc.wait(timeout=60)
        self._reader.join(timeout=5)
        return rc


def test_clients_attach_to_fixstream_up_with_no_flags_even_off_the_default_port(tmp_path: Path) -> None:
    """The default port (7447) is taken by something else: ``up`` runs its router elsewhere, says where, and
    ``status``, ``echo``, ``record`` and a library client find it with no flags and no environment. (A port asked
    for, by FIXSTREAM_ROUTER_PORT or --router-port, is never replaced: tests/test_audit_stack.py.)"""
    (tmp_path / "compose.yaml").write_text(COMPOSE)
    busy = DEFAULT_ROUTER_PORT
    blocker = socket.socket()
    blocker.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the router binds: TIME_WAIT is no use
    with contextlib.suppress(OSError):  # a listener there already (another stack): as busy as we need it
        blocker.bind(("127.0.0.1", busy))
        blocker.listen()
    up = _Up(tmp_path, _client_env())
    record: subprocess.Popen[str] | None = None
    try:
        assert wait_until(lambda: up.saw("lbl_nav-x ready") and up.saw("recorder ready"), timeout=90), up.lines
        endpoint = next(line for line in up.lines if "router on tcp/" in line).split("router on ")[1].split(";")[0]
        assert not endpoint.endswith(f":{busy}")
        assert [s.endpoint for s in local_stack.running_stacks()] == [endpoint]

        assert _statuses() == [("lbl_nav", "x"), ("recorder", "att")]

        echo = subprocess.Popen(
            fixstream_cmd("echo", "fixstream/sensor/**", "--json", "--count", "1", "--timeout", "60"),
            cwd=REPO,
            env=_client_env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        session = open_session(ZenohSettings())  # the library's defaults find the stack too
        try:
            pub = session.declare_publisher("fixstream/sensor/v/depth/d")
            depth = EXAMPLES["Depth"]
            # until echo has subscribed and printed its one message (it exits after --count 1)
            deadline = time.monotonic() + 60
            while echo.poll() is None and time.monotonic() < deadline:
                pub.put(codec.encode(depth), encoding=zenoh.Encoding(codec.encoding_of(Depth)))
                time.sleep(0.3)
            out, err = echo.communicate(timeout=60)
        finally:
            session.close()
        assert echo.returncode == 0, err
        assert json.loads(out.splitlines()[0])["message"] == depth.model_dump(mode="json")

        record = subprocess.Popen(
            fixstream_cmd("record", "--out-dir", str(tmp_path / "rec2"), "--instance", "cli"),
            cwd=REPO,
            env=_client_env(),
            text=True,
        )
        assert wait_until(lambda: ("recorder", "cli") in _statuses(), timeout=60)
    finally:
        if record is not None:
            record.terminate()
            assert record.wait(timeout=30) == 0
        rc = up.stop()
        blocker.close()
    assert rc in (0, 130), up.lines
    assert local_stack.running_stacks() == []


def test_the_embedded_router_takes_the_published_port_when_it_is_free(tmp_path: Path) -> None:
    from tools.stack import load_compose, plan_stack

    (tmp_path / "compose.yaml").write_text(COMPOSE)
    port = free_tcp_port()
    project = load_compose(tmp_path / "compose.yaml", environ={**os.environ, "FIXSTREAM_ROUTER_PORT": str(port)})
    plan = plan_stack(project, ["router"], create_dirs=False)
    assert plan.endpoint == f"tcp/127.0.0.1:{port}"
    assert plan_stack(project, ["router"], create_dirs=False, router_port=0).endpoint != plan.endpoint


# --- bad starts: one line, exit code 2 ------------------------------------------------------------------------------


def _no_router() -> str:
    return f"tcp/127.0.0.1:{free_tcp_port()}"


BAD_STARTS: list[tuple[list[str], dict[str, str], str]] = [
    (
        ["run", "recorder"],
        {"FIXSTREAM_ZENOH_CONNECT": "NOROUTER", "FIXSTREAM_ZENOH_CONNECT_TIMEOUT_S": "0.5"},
        "FIXSTREAM_ZENOH_CONNECT",
    ),
    (["status", "--connect", "NOROUTER", "--connect-timeout", "0.5"], {}, "no Zenoh router reachable"),
    (["echo", "--connect", "NOROUTER", "--connect-timeout", "0"], {}, "no Zenoh router reachable"),
    (["run", "terrain_nav"], {}, "FIXSTREAM_TERRAIN_NAV_MAP_PATH: missing"),
    (["run", "terrain_nav"], {"FIXSTREAM_TERRAIN_NAV_MAP_PATH": "/nonexistent/map"}, "does not exist"),
    (["run", "no_such_service"], {}, "no plugin named 'no_such_service'"),
    (["status"], {"FIXSTREAM_ZENOH_CONNECT_TIMEOUT_S": "soon"}, "FIXSTREAM_ZENOH_CONNECT_TIMEOUT_S"),
    (["run", "lbl_nav"], {"FIXSTREAM_LBL_NAV_QUEUE_SIZE": "0"}, "FIXSTREAM_LBL_NAV_QUEUE_SIZE"),
]


@pytest.mark.parametrize(("argv", "env", "says"), BAD_STARTS, ids=lambda v: "_".join(v) if isinstance(v, list) else "")
def test_a_bad_start_is_one_line_and_exit_code_2(argv: list[str], env: dict[str, str], says: str) -> None:
    endpoint = _no_router()
    argv = [a.replace("NOROUTER", endpoint) for a in argv]
    env = {k: v.replace("NOROUTER", endpoint) for k, v in env.items()}
    done = subprocess.run(
        fixstream_cmd(*argv), cwd=REPO, env=_client_env(**env), capture_output=True, text=True, timeout=60
    )
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert says in lines[0] and lines[0].startswith("fixstream "), lines


def test_a_bad_key_expression_is_a_usage_error() -> None:
    done = subprocess.run(
        fixstream_cmd("echo", "a/**/**/b"), cwd=REPO, env=_client_env(), capture_output=True, text=True
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.splitlines()[-1].endswith("not a valid Zenoh key expression: 'a/**/**/b'")


# --- a service that starts before its router; a router that restarts ----------------------------------------------


def _router_on(endpoint: str) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        fixstream_cmd("router", "--listen", endpoint),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and "listening" in proc.stdout.readline()
    return proc


def _stop(proc: subprocess.Popen[str]) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def test_a_service_started_before_its_router_joins_when_the_router_comes(tmp_path: Path) -> None:
    endpoint = _no_router()
    svc = subprocess.Popen(
        fixstream_cmd("run", "lbl_nav"),
        env=service_env(endpoint, FIXSTREAM_LBL_NAV_INSTANCE="early", FIXSTREAM_ZENOH_CONNECT_TIMEOUT_S="60"),
        cwd=REPO,
        text=True,
    )
    router = None
    try:
        time.sleep(3.0)  # 20x the 0.14 s after which a client session used to give up
        assert svc.poll() is None, "the service died waiting for its router"
        router = _router_on(endpoint)
        watch = open_session(ZenohSettings(mode="client", connect=[endpoint]))
        try:  # the session retries with Zenoh's back-off (1 s doubling to 4 s)
            assert wait_until(lambda: _alive_count(watch, keys.alive("lbl_nav", "early")) == 1, timeout=30)
        finally:
            watch.close()
        assert _statuses("--connect", endpoint) == [("lbl_nav", "early")]
    finally:
        svc.terminate()
        assert svc.wait(timeout=30) == 0
        if router is not None:
            _stop(router)


def _depth(seq_stamp: int) -> Depth:
    return Depth(header=Header(stamp_ns=seq_stamp * 1_000_000, frame_id="v"), depth_m=10.0)


def test_services_resume_after_the_router_restarts_and_count_what_was_lost(tmp_path: Path) -> None:
    """Kill the router mid-run and start it again on the same port. Every service resumes by itself.

    Loss, by construction: Zenoh keeps no copy of what is published while no router routes it, so the batch
    published during the outage (``during``) is lost for every subscriber, and nothing else is: the batches before
    the kill and after the subscribers' declarations are routed again arrive whole. The recorder sees the gap in
    the publisher's seq and counts exactly ``during`` as lost."""
    endpoint = _no_router()
    routers = [_router_on(endpoint)]
    key = "fixstream/sensor/rr/depth/d"
    specs = [
        ("recorder", {"FIXSTREAM_RECORDER_INSTANCE": "rr", "FIXSTREAM_RECORDER_OUT_DIR": str(tmp_path)}),
        ("lbl_nav", {"FIXSTREAM_LBL_NAV_INSTANCE": "rr"}),
    ]
    before, during, after = 200, 50, 300
    try:
        with _services(endpoint, specs) as procs:
            client = open_session(ZenohSettings(mode="client", connect=[endpoint], connect_timeout_s=30))
            try:
                assert wait_until(lambda: _alive_count(client) == 2, timeout=60)
                pub = client.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
                seq = 0

                def send(n: int) -> None:
                    nonlocal seq
                    for _ in range(n):
                        msg = _depth(seq)
                        pub.put(
                            codec.encode_stamped(msg, "test/rr", seq), encoding=zenoh.Encoding(codec.encoding_of(Depth))
                        )
                        seq += 1

                def received() -> dict[str, int]:
                    out: dict[str, int] = {}
                    for reply in client.get(
                        "fixstream/status/**",
                        target=zenoh.QueryTarget.ALL,
                        consolidation=zenoh.ConsolidationMode.NONE,
                        timeout=2.0,
                    ):
                        if reply.ok is not None:
                            body: dict[str, Any] = json.loads(reply.ok.payload.to_bytes())
                            out[body["service"]] = body["counters"]["received"]
                    return out

                send(before)
                assert wait_until(lambda: received() == {"recorder": before, "lbl_nav": before}, timeout=30)
                routers[-1].kill()
                routers[-1].wait()
                assert wait_until(lambda: not pub.matching_status.matching, timeout=30)
                send(during)
                routers.append(_router_on(endpoint))
                # both subscribers declared again through the new router: wait until the client can see them
                assert wait_until(lambda: _alive_count(client) == 2, timeout=60)
                assert wait_until(lambda: pub.matching_status.matching, timeout=30)
                time.sleep(1.0)  # the second subscriber's declaration may follow the first one's
                send(after)
                # lbl_nav listens to the vehicle's sensors only; the recorder also gets the stack's diagnostics
                assert wait_until(lambda: received()["lbl_nav"] == before + after, timeout=60), received()
                assert wait_until(lambda: received()["recorder"] >= before + after, timeout=60), received()
                replies = list(client.get(keys.status("recorder", "rr"), timeout=5.0))
                status = json.loads(replies[0].ok.payload.to_bytes())  # type: ignore[union-attr]
                assert status["lost"] == during and status["seq_gaps"] == 1
                assert all(p.poll() is None for p in procs), "a service died with its router"
            finally:
                client.close()
    finally:
        for r in routers:
            _stop(r)
    written = [r for f in recording_files(tmp_path) for r in iter_records(f) if r.topic == key]
    stamps = [decode_record(r).header.stamp_ns // 1_000_000 for r in written]
    assert stamps == [*range(before), *range(before + during, before + during + after)]
