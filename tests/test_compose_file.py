"""compose.yaml checked by a real compose implementation (Debian's docker-compose, no engine needed), and
``fixstream up``'s reading of it compared with compose's own."""

from __future__ import annotations

import copy
import os
import shutil
import subprocess
from importlib.metadata import version
from pathlib import Path
from typing import Any

import pytest
import yaml

from tools.stack import load_compose

REPO = Path(__file__).resolve().parent.parent
COMPOSE = REPO / "compose.yaml"


def docker_compose(*args: str, env: dict[str, str] | None = None, cwd: Path = REPO) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("docker-compose")
    if exe is None:
        pytest.fail(
            "docker-compose is not installed: `make tools` installs it (Debian package docker-compose), "
            "it validates compose.yaml without a Docker engine"
        )
    return subprocess.run(
        [exe, *args], cwd=cwd, env=env or dict(os.environ), capture_output=True, text=True, timeout=120
    )


def compose_config(path: Path, env: dict[str, str]) -> dict[str, Any]:
    key = (path, tuple(sorted(env.items())))
    if key not in _CONFIGS:
        proc = docker_compose("-f", str(path), "config", env=env, cwd=path.parent)
        assert proc.returncode == 0, proc.stderr
        _CONFIGS[key] = yaml.safe_load(proc.stdout)
    data = _CONFIGS[key]
    assert isinstance(data, dict)
    return copy.deepcopy(data)


_CONFIGS: dict[tuple[Path, tuple[tuple[str, str], ...]], Any] = {}


def clean_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("FIXSTREAM_", "COMPOSE_", "T_"))}
    env.update(extra)
    return env


def test_compose_file_is_valid() -> None:
    proc = docker_compose("-f", str(COMPOSE), "config", "-q", env=clean_env())
    assert proc.returncode == 0, proc.stderr


def test_router_image_pinned_to_the_python_zenoh_version() -> None:
    config = compose_config(COMPOSE, clean_env())
    assert config["services"]["router"]["image"] == f"eclipse/zenoh:{version('eclipse-zenoh')}"
    command = config["services"]["router"]["command"]
    assert command[:2] == ["--listen", "tcp/0.0.0.0:7447"]  # zenohd's flag, passed by the image's entrypoint


def test_stack_services_follow_the_conventions() -> None:
    config = compose_config(COMPOSE, clean_env())
    services = config["services"]
    assert {"router", "recorder", "player"} <= set(services)
    drivers = [n for n, s in services.items() if (s.get("labels") or {}).get("fixstream.role") == "driver"]
    assert drivers == ["player"]
    for name, svc in services.items():
        if name == "router":
            continue
        assert svc["image"] == "fixstream:latest" and svc["build"]["context"] == str(REPO), name
        assert svc["command"][0] == "fixstream", name
        assert svc["environment"]["FIXSTREAM_ZENOH_CONNECT"] == "tcp/router:7447", name
        assert "router" in svc["depends_on"], name
    assert services["recorder"]["environment"]["FIXSTREAM_RECORDER_OUT_DIR"] == "/data/recordings"
    # servers are started again by the engine when they die; the driver is a run and is not
    restarts = {name: svc.get("restart", "no") for name, svc in services.items()}
    assert restarts == {name: "no" if name in drivers else "unless-stopped" for name in services}, restarts
    assert services["recorder"]["volumes"][0].startswith(f"{REPO}/recordings:/data/recordings")


@pytest.mark.parametrize(
    "env",
    [
        {},
        {"FIXSTREAM_SCENARIO": "/tmp/other.yaml", "FIXSTREAM_RATE": "10", "FIXSTREAM_RECORDINGS": "/tmp/rec"},
        {"FIXSTREAM_RATE": "", "FIXSTREAM_LOG_LEVEL": "DEBUG"},
    ],
)
def test_fixstream_up_reads_compose_yaml_like_compose(env: dict[str, str]) -> None:
    """Commands, environment and bind volumes as ``fixstream up`` parses them equal compose's own result."""
    full_env = clean_env(**env)
    theirs = compose_config(COMPOSE, full_env)["services"]
    ours = load_compose(COMPOSE, environ=full_env).services
    assert set(ours) == set(theirs)
    for name, spec in ours.items():
        assert spec.command == theirs[name].get("command", []), name
        assert spec.environment == (theirs[name].get("environment") or {}), name
        binds = [f"{v.source}:{v.target}" for v in spec.volumes]
        assert binds == [v.rsplit(":", 1)[0] for v in theirs[name].get("volumes", [])], name


def test_interpolation_agrees_with_docker_compose(tmp_path: Path) -> None:
    """The interpolation rules both implementations share (docker-compose 1.29 lacks nesting and ``:+``)."""
    exprs = {
        "T1": "${T_SET}",
        "T2": "$T_SET/suffix",
        "T3": "${T_UNSET:-default}",
        "T4": "${T_EMPTY:-default}",
        "T5": "${T_EMPTY-default}",
        "T6": "${T_UNSET-default}",
        "T7": "$${T_SET} and $$T_SET",
        "T8": "${T_SET:?required}",
        "T9": "${T_EMPTY?required}",
        "T10": "${T_DOTENV}-${T_BOTH}",
        "T11": "${T_UNSET:-a:b/c-d}",
    }
    body = "\n".join(f"      {k}: '{v}'" for k, v in exprs.items())
    path = tmp_path / "compose.yaml"
    path.write_text(f"services:\n  probe:\n    image: busybox\n    environment:\n{body}\n")
    (tmp_path / ".env").write_text("T_DOTENV=from-dotenv\nT_BOTH=from-dotenv\n")
    env = clean_env(T_SET="value", T_EMPTY="", T_BOTH="from-shell")
    # `config` prints a compose file again, so it escapes literal dollars back to $$
    theirs = {k: v.replace("$$", "$") for k, v in compose_config(path, env)["services"]["probe"]["environment"].items()}
    ours = load_compose(path, environ=env).services["probe"].environment
    assert ours == theirs
    assert ours["T7"] == "${T_SET} and $T_SET"
    assert ours["T10"] == "from-dotenv-from-shell"


def test_missing_required_variable_fails_in_both(tmp_path: Path) -> None:
    path = tmp_path / "compose.yaml"
    path.write_text("services:\n  probe:\n    image: busybox\n    command: ['${T_NEEDED:?set T_NEEDED}']\n")
    proc = docker_compose("-f", str(path), "config", "-q", env=clean_env(), cwd=tmp_path)
    assert proc.returncode != 0 and "set T_NEEDED" in proc.stderr
    from tools.stack import ComposeError

    with pytest.raises(ComposeError, match="set T_NEEDED"):
        load_compose(path, environ=clean_env())
