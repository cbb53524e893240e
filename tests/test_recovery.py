"""Control streams recovered after a router outage (shared/recovery.py), over real sockets with real processes.

The failure this guards against was found in a container stack whose router crashed: the player's ``VehicleStatus``
for auv3, the last message on its key, fell into the outage, the coordinator never answered it, and auv3's whole
mission vanished (docs/stack.md, "When the router restarts"). Here a ``fixstream router`` is SIGKILLed while a
client publishes on a group's uplink, and started again on the same port: with the default recovery keys the
coordinator (``fixstream run coordinator``, its own process) answers every input published during the outage, once
each, and its answers come back to the client; with recovery turned off (``FIXSTREAM_ZENOH_RECOVERY_KEYS=``) the
same inputs are never answered, which shows that the outage does lose them and that recovery is what brings them
back.
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import zenoh
from conftest import REPO, fixstream_cmd, service_env, wait_until
from hypothesis import given
from hypothesis import strategies as st

from schemas import Header
from schemas.rd_nav import CoordinatorReply, VehicleStatus
from services.coordinator.service import reply_key, uplink_key
from services.player.publish import Publishers
from shared import codec, keys
from shared.recovery import Recovery
from shared.session import free_tcp_port, open_session
from shared.settings import ZenohSettings
from tools.stack.pki import ROUTER_ACL, Pki, make_pki

GROUP = "group1"
SOURCE = "player/default"
#: how long the router stays down, s
OUTAGE_S = 2.0
#: how long the inputs of the outage may take to be answered once the router is back, s (Zenoh reconnects within
#: its back-off of up to 4 s, then a heartbeat every 0.5 s: 10 s is more than twice that)
ANSWER_WITHIN_S = 10.0

CHUNK = st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789_-", min_size=1, max_size=8)


@given(first=st.sampled_from(["group", "scenario", "sensor", "fix", "diag", "truth"]), rest=st.lists(CHUNK, max_size=4))
def test_the_default_recovery_keys_cover_the_control_streams_and_no_wider_subscription(
    first: str, rest: list[str]
) -> None:
    """A key, or a subscription, is recovered when it lies wholly inside ``fixstream/group/**`` or
    ``fixstream/scenario/**``: checked against its first chunk. A subscription wider than those (the recorder's
    ``fixstream/**``) is not: an advanced subscriber would order plain publishers' samples by router timestamp."""
    recovery = Recovery(("fixstream/group/**", "fixstream/scenario/**"))
    key = "/".join(["fixstream", first, *rest])
    control = first in ("group", "scenario")
    assert recovery.covers(key) is control
    assert recovery.covers(key + "/**") is control
    assert not recovery.covers("fixstream/**") and not recovery.covers("fixstream/*/x")
    assert not Recovery(()).covers(key)


def test_the_settings_default_to_the_control_streams(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("FIXSTREAM_ZENOH_RECOVERY_KEYS", raising=False)
    assert Recovery.of(ZenohSettings()).keys == ("fixstream/group/**", "fixstream/scenario/**")
    monkeypatch.setenv("FIXSTREAM_ZENOH_RECOVERY_KEYS", "")
    assert Recovery.of(ZenohSettings()).keys == ()


def _tls_env(pki: Pki | None, identity: str) -> dict[str, str]:
    if pki is None:
        return {}
    ident = pki.identity(identity)
    return {
        "FIXSTREAM_ZENOH_TLS_ROOT_CA": str(pki.ca),
        "FIXSTREAM_ZENOH_TLS_CERT": str(ident.cert),
        "FIXSTREAM_ZENOH_TLS_KEY": str(ident.key),
    }


def _start_router(endpoint: str, pki: Pki | None) -> subprocess.Popen[str]:
    """``fixstream router``; with ``pki``, over mutual TLS with the secure stack's access control."""
    config = ["--config", str(ROUTER_ACL)] if pki is not None else []
    base = {k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_ZENOH_")}
    proc = subprocess.Popen(
        fixstream_cmd("router", "--listen", endpoint, *config),
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        cwd=REPO,
        env={**base, **_tls_env(pki, "router")},
    )
    assert proc.stdout is not None
    assert "listening" in proc.stdout.readline(), "router did not start"
    return proc


@contextmanager
def _coordinator(
    endpoint: str, recovery_keys: str | None, pki: Pki | None, log: Path
) -> Iterator[subprocess.Popen[bytes]]:
    extra = {"FIXSTREAM_COORDINATOR_INSTANCE": GROUP, **_tls_env(pki, "coordinator")}
    if recovery_keys is not None:
        extra["FIXSTREAM_ZENOH_RECOVERY_KEYS"] = recovery_keys
    with log.open("wb") as out:
        proc = subprocess.Popen(
            fixstream_cmd("run", "coordinator"), env=service_env(endpoint, **extra), cwd=REPO, stdout=out, stderr=out
        )
        try:
            yield proc
        finally:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()


def _status(auv: str, t_s: float, seq: int) -> VehicleStatus:
    header = Header(stamp_ns=round(t_s * 1e9), source=SOURCE, seq=seq)
    return VehicleStatus(header=header, auv_id=auv, event="DOCKED", node_id="base")


def _outage(
    tmp_path: Path, recovery_keys: str | None, secure: bool = False
) -> tuple[list[tuple[str, int]], list[tuple[str, int]]]:
    """One input answered before the outage, two published while the router is down (the last on its key, and the
    only one on its key); returns the (key, seq) inputs of the outage and the answers received, in order. ``secure``:
    over mutual TLS, with the secure stack's access control, the client holding the player's identity."""
    pki = make_pki(tmp_path / "pki") if secure else None
    endpoint = f"{'tls' if secure else 'tcp'}/127.0.0.1:{free_tcp_port()}"
    router = _start_router(endpoint, pki)
    tls: dict[str, Any] = {}
    if pki is not None:
        player = pki.identity("player")
        tls = {"tls_root_ca": pki.ca, "tls_cert": player.cert, "tls_key": player.key}
    settings = ZenohSettings(mode="client", connect=[endpoint], connect_timeout_s=10.0, **tls)
    if recovery_keys is not None:
        settings = settings.model_copy(update={"recovery_keys": [k for k in recovery_keys.split(",") if k]})
    recovery = Recovery.of(settings)
    answers: list[tuple[str, int]] = []
    lock = threading.Lock()

    def on_reply(sample: zenoh.Sample) -> None:
        msg = codec.decode(sample.payload.to_bytes(), str(sample.encoding))
        assert isinstance(msg, CoordinatorReply)
        with lock:
            answers.append((msg.input_key, msg.input_seq))

    session = open_session(settings)
    try:
        with _coordinator(endpoint, recovery_keys, pki, tmp_path / "coordinator.log"):
            sub = recovery.declare_subscriber(session, reply_key(GROUP), on_reply)
            alive = keys.alive("coordinator", GROUP)
            assert wait_until(lambda: any(True for _ in session.liveliness().get(alive, timeout=0.5)), 30.0)
            pubs = Publishers(session, recovery)
            auv1, auv3 = uplink_key(GROUP, "auv1", "status"), uplink_key(GROUP, "auv3", "status")
            pubs.put_stamped(auv1, _status("auv1", 1.0, 0), SOURCE, 0)
            assert wait_until(lambda: (auv1, 0) in answers, 10.0), "the loop does not answer before the outage"
            router.send_signal(signal.SIGKILL)
            router.wait()
            time.sleep(0.2)
            pubs.put_stamped(auv3, _status("auv3", 2.0, 0), SOURCE, 0)  # the only message on its key
            pubs.put_stamped(auv1, _status("auv1", 3.0, 1), SOURCE, 1)  # the last message on its key
            time.sleep(OUTAGE_S)
            router = _start_router(endpoint, pki)
            lost = [(auv3, 0), (auv1, 1)]
            wait_until(lambda: all(a in answers for a in lost), ANSWER_WITHIN_S)
            time.sleep(1.0)  # a duplicate answer would come now
            sub.undeclare()
            pubs.close()
    finally:
        session.close()
        router.terminate()
        router.wait(timeout=10)
    with lock:
        return lost, list(answers)


@pytest.mark.parametrize("secure", [False, True], ids=["tcp", "secure"])
def test_control_messages_published_while_the_router_is_down_are_answered_once_it_is_back(
    tmp_path: Path, secure: bool
) -> None:
    """Also through the secure stack's router: its access control lets the player and the coordinator keep their
    caches and answer from them (``<key>/@adv/**``), and everyone subscribe and query there."""
    lost, answers = _outage(tmp_path, None, secure)
    assert answers[0] == (lost[1][0], 0)
    assert sorted(answers[1:]) == sorted(lost), f"answers {answers}, outage inputs {lost}"


def test_without_recovery_the_same_outage_loses_them(tmp_path: Path) -> None:
    """The control: the same run with plain publishers and subscribers never answers the outage's inputs."""
    lost, answers = _outage(tmp_path, "")
    assert answers == [(lost[1][0], 0)], f"answers {answers}"
