"""The secure stack over real TLS on loopback: who may publish what is the router's job (architecture rule 10).

A router with the repository's access control (tools/stack/router-secure.json5), services with the identities of
their roles, and a client holding a valid certificate of the read-only ``client`` identity (or of another
estimator) that tries every impersonation issue 14 names: a fix, a grant, an end marker, a liveliness token. None
reaches a service or the recording; the genuine publishers' messages do (the positive control); a process with no
certificate cannot even connect.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import zenoh
from conftest import REPO, fixstream_cmd, wait_until

from schemas import Depth, Header, ScenarioMarker
from shared import codec, keys, local_stack
from shared.mcap_io import iter_records, recording_files
from shared.session import free_tcp_port, open_session, query_all
from shared.settings import ZenohSettings
from tools.stack.pki import ROUTER_ACL, Pki, make_pki

pytestmark = pytest.mark.e2e


def _tls_env(pki: Pki, identity: str) -> dict[str, str]:
    ident = pki.identity(identity)
    return {
        "FIXSTREAM_ZENOH_TLS_ROOT_CA": str(pki.ca),
        "FIXSTREAM_ZENOH_TLS_CERT": str(ident.cert),
        "FIXSTREAM_ZENOH_TLS_KEY": str(ident.key),
    }


def _session(pki: Pki, endpoint: str, identity: str) -> zenoh.Session:
    ident = pki.identity(identity)
    return open_session(
        ZenohSettings(mode="client", connect=[endpoint], tls_root_ca=pki.ca, tls_cert=ident.cert, tls_key=ident.key)
    )


def _put(session: zenoh.Session, key: str, msg: Any, source: str, seq: int = 0) -> None:
    session.put(key, codec.encode_stamped(msg, source, seq), encoding=zenoh.Encoding(codec.encoding_of(type(msg))))


def test_only_the_right_identity_publishes_and_impersonation_never_arrives(tmp_path: Path) -> None:
    pki = make_pki(tmp_path / "pki")
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    base = {k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_ZENOH_")}
    router = subprocess.Popen(
        fixstream_cmd("router", "--listen", endpoint, "--config", str(ROUTER_ACL)),
        cwd=REPO,
        env={**base, **_tls_env(pki, "router")},
        stdout=subprocess.PIPE,
        text=True,
    )
    assert router.stdout is not None and "listening" in router.stdout.readline()
    svc_env = {**base, "FIXSTREAM_ZENOH_MODE": "client", "FIXSTREAM_ZENOH_CONNECT": endpoint}
    services = [
        ("recorder", {"FIXSTREAM_RECORDER_INSTANCE": "sec", "FIXSTREAM_RECORDER_OUT_DIR": str(tmp_path / "rec")}),
        ("lbl_nav", {"FIXSTREAM_LBL_NAV_INSTANCE": "lbl1"}),
        ("coordinator", {"FIXSTREAM_COORDINATOR_INSTANCE": "group1"}),
    ]
    procs = [
        subprocess.Popen(fixstream_cmd("run", name), cwd=REPO, env={**svc_env, **_tls_env(pki, name), **env})
        for name, env in services
    ]
    reader = _session(pki, endpoint, "client")
    try:
        alive = ["fixstream/alive/recorder/sec", "fixstream/alive/lbl_nav/lbl1", "fixstream/alive/coordinator/group1"]

        def tokens() -> list[str]:
            return sorted(str(r.ok.key_expr) for r in reader.liveliness().get("fixstream/alive/**", timeout=1) if r.ok)

        assert wait_until(lambda: tokens() == sorted(alive), timeout=60), tokens()

        # the attacks: a client identity and another estimator's identity, both with valid certificates
        marker = ScenarioMarker(header=Header(stamp_ns=1), event="end", scenario="demo", seed=0)
        fix_like = Depth(header=Header(stamp_ns=5), depth_m=1.0)
        for attacker in ("client", "rd_nav"):
            evil = _session(pki, endpoint, attacker)
            try:
                _put(evil, "fixstream/fix/lbl/lbl1", fix_like, "lbl_nav/lbl1")
                _put(evil, "fixstream/group/group1/grant/auv3", fix_like, "coordinator/group1")
                _put(evil, "fixstream/group/group1/assignment", fix_like, "coordinator/group1")
                _put(evil, keys.scenario("demo"), marker, "player/default")
                _put(evil, "fixstream/sensor/lbl1/depth/d0", fix_like, "player/default")
                token = evil.liveliness().declare_token("fixstream/alive/lbl_nav/fake")
                time.sleep(1.0)
                assert tokens() == sorted(alive)  # the forged token is not routed
                token.undeclare()
            finally:
                evil.close()
        # the positive control: the player's identity feeds sensors and markers, lbl_nav's writes its own keys
        player = _session(pki, endpoint, "player")
        lbl = _session(pki, endpoint, "lbl_nav")
        try:
            _put(player, "fixstream/sensor/lbl1/depth/d0", fix_like, "player/default")
            _put(lbl, "fixstream/fix/lbl/probe", fix_like, "lbl_nav/probe")
            time.sleep(1.0)
        finally:
            player.close()
            lbl.close()

        status = {}
        for reply in query_all(reader, "fixstream/status/**", 5.0):  # the client identity may read
            assert reply.ok is not None
            body = json.loads(reply.ok.payload.to_bytes())
            status[body["service"]] = body
        assert sorted(status) == ["coordinator", "lbl_nav", "recorder"]
        assert status["lbl_nav"]["counters"]["received"] == 1  # the player's depth only: no forged sensor or marker
        assert status["lbl_nav"]["scenario"]["ends"] == {}
        assert status["coordinator"]["counters"]["received"] == 0

        # no certificate at all: not even a connection
        with pytest.raises(Exception, match="no Zenoh router reachable"):
            open_session(ZenohSettings(mode="client", connect=[endpoint], connect_timeout_s=1))
    finally:
        reader.close()
        for p in procs:
            p.terminate()
        for p in procs:
            assert p.wait(timeout=30) == 0
        router.terminate()
        router.wait(timeout=30)
    written = [(r.topic, r.data) for f in recording_files(tmp_path / "rec") for r in iter_records(f)]
    topics = {t for t, _ in written}
    assert "fixstream/fix/lbl/probe" in topics and "fixstream/sensor/lbl1/depth/d0" in topics
    assert not topics & {"fixstream/fix/lbl/lbl1", "fixstream/group/group1/grant/auv3", "fixstream/scenario/demo"}
    assert sum(1 for t, _ in written if t == "fixstream/sensor/lbl1/depth/d0") == 1


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
      FIXSTREAM_RECORDER_INSTANCE: sec
      FIXSTREAM_RECORDER_OUT_DIR: /data/rec
    volumes: ["./rec:/data/rec"]
    depends_on: [router]
  lbl_nav-lbl1:
    image: fixstream:latest
    command: ["fixstream", "run", "lbl_nav"]
    environment:
      FIXSTREAM_ZENOH_CONNECT: tcp/router:7447
      FIXSTREAM_LBL_NAV_INSTANCE: lbl1
    depends_on: [router]
"""


def test_up_secure_runs_over_tls_and_clients_attach_read_only_with_no_flags(tmp_path: Path) -> None:
    (tmp_path / "compose.yaml").write_text(COMPOSE)
    env = {k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_") or k == "FIXSTREAM_STATE_DIR"}
    up = subprocess.Popen(
        fixstream_cmd("up", "-f", str(tmp_path / "compose.yaml"), "--secure", "--router-port", "0", "--no-color"),
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(ln.rstrip() for ln in up.stdout or []), daemon=True).start()
    try:
        assert wait_until(lambda: sum(" ready: fixstream/alive/" in ln for ln in lines) == 2, timeout=120), lines
        (stack,) = local_stack.running_stacks()
        assert stack.endpoint.startswith("tls/127.0.0.1:") and stack.tls
        done = subprocess.run(
            fixstream_cmd("status", "--json"), cwd=REPO, env=env, capture_output=True, text=True, timeout=60
        )
        assert done.returncode == 0, done.stderr
        assert sorted(json.loads(ln)["service"] for ln in done.stdout.splitlines()) == ["lbl_nav", "recorder"]
        # the client identity may read but not feed: a depth from it never reaches lbl_nav
        client = open_session(ZenohSettings())
        try:
            _put(client, "fixstream/sensor/lbl1/depth/d0", Depth(header=Header(stamp_ns=1), depth_m=1.0), "player/x")
            time.sleep(1.0)
            (reply,) = query_all(client, keys.status("lbl_nav", "lbl1"), 5.0)
            assert reply.ok is not None and json.loads(reply.ok.payload.to_bytes())["counters"]["received"] == 0
        finally:
            client.close()
    finally:
        up.send_signal(signal.SIGINT)
        rc = up.wait(timeout=60)
    assert rc in (0, 130), lines[-20:]
