"""The Zenoh configuration every fixstream process opens its session with.

Zenoh's implicit shared-memory transport moves payloads of 3 KiB and more between local processes through a
shared pool whose buffers a watchdog invalidates when the reader is late: a busy subscriber (the recorder at
``--rate 0``) then loses those messages with no error anywhere. Measured on the demo before the fix: 7 of 61 PCL
scans (every one of them ≥ 3,072 bytes) missing from the recording while a fast subscriber got all 61; the end-to-end
test ``test_compose_e2e`` counts every scan of the demo in the recording and fails on it.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import yaml
from conftest import REPO

from shared.session import zenoh_config
from shared.settings import ZenohSettings


def test_implicit_shared_memory_is_off_unless_asked(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("FIXSTREAM_ZENOH_SHARED_MEMORY", raising=False)
    assert json.loads(zenoh_config(ZenohSettings()).get_json("transport/shared_memory/enabled")) is False
    monkeypatch.setenv("FIXSTREAM_ZENOH_SHARED_MEMORY", "true")
    assert json.loads(zenoh_config(ZenohSettings()).get_json("transport/shared_memory/enabled")) is True


def test_router_settings_reach_the_zenoh_config() -> None:
    cfg = zenoh_config(ZenohSettings(mode="router", listen=["tcp/127.0.0.1:0"], block_close_s=60.0))
    assert json.loads(cfg.get_json("transport/link/tx/queue/congestion_control/block/wait_before_close")) == 60_000_000
    assert json.loads(cfg.get_json("mode")) == "router"


def test_compose_router_has_no_shared_memory_and_waits_for_slow_links() -> None:
    router = yaml.safe_load((REPO / "compose.yaml").read_text())["services"]["router"]
    command = router["command"]
    cfgs = [command[i + 1] for i, arg in enumerate(command) if arg == "--cfg"]
    assert "transport/shared_memory/enabled:false" in cfgs
    assert "transport/link/tx/queue/congestion_control/block/wait_before_close:60000000" in cfgs


def test_an_unreadable_tls_key_is_named_before_zenoh_tries(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A key the process cannot read (compose.secure.yaml's services run as uid 10001; `fixstream pki` writes keys
    0600 for whoever ran it) fails at once with its path, not as "no router reachable" after the connect timeout.
    Unreadability is simulated: this suite may run as root, who reads every file."""
    from shared.errors import ConnectError
    from tools.stack.pki import make_pki

    pki = make_pki(tmp_path / "pki", identities=("lbl_nav",))
    ident = pki.identity("lbl_nav")
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: Path(p) != ident.key and real_access(p, mode))
    settings = ZenohSettings(connect=["tls/127.0.0.1:1"], tls_root_ca=pki.ca, tls_cert=ident.cert, tls_key=ident.key)
    with pytest.raises(ConnectError, match=f"TLS file not readable by this user .*: {ident.key}$"):
        zenoh_config(settings)
    monkeypatch.setattr(os, "access", real_access)
    zenoh_config(settings)  # readable: the same settings make a configuration
