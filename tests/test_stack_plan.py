"""Compose parsing and the compose -> local process mapping (no processes started)."""

from __future__ import annotations

import signal
import sys
from pathlib import Path

import pytest

from tools.stack import ComposeError, load_compose, plan_stack
from tools.stack.compose import find_compose_file, parse_duration
from tools.stack.plan import FIXSTREAM_ARGV

REPO = Path(__file__).resolve().parent.parent


def write(tmp_path: Path, text: str, name: str = "compose.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_repo_compose_maps_to_local_processes(tmp_path: Path) -> None:
    project = load_compose(REPO / "compose.yaml", environ={"PATH": "/usr/bin"})
    names = project.select()
    assert names[:2] == ["router", "recorder"] and names[-1] == "player"
    plan = plan_stack(project, names, environ={"PATH": "/usr/bin"}, create_dirs=False)
    procs = {p.service: p for p in plan.processes}

    router = procs["router"]
    assert router.router_port is not None
    assert router.argv == [*FIXSTREAM_ARGV, "router", "--listen", f"tcp/127.0.0.1:{router.router_port}"]
    assert plan.endpoint == f"tcp/127.0.0.1:{router.router_port}"

    recorder = procs["recorder"]
    assert recorder.argv == [*FIXSTREAM_ARGV, "run", "recorder"]
    assert recorder.env["FIXSTREAM_ZENOH_CONNECT"] == plan.endpoint
    assert recorder.env["FIXSTREAM_ZENOH_MODE"] == "client"
    assert recorder.env["FIXSTREAM_RECORDER_OUT_DIR"] == str(REPO / "recordings")
    assert recorder.ready_key == "fixstream/alive/recorder/main"
    assert recorder.stop_timeout == 20.0
    assert REPO / "recordings" in plan.output_dirs

    player = procs["player"]
    assert player.driver and not recorder.driver
    # a recorded run waits for the recorder whatever the scenario's wait_for says (issue 13 item 5)
    assert player.argv == [*FIXSTREAM_ARGV, "play", "scenarios/demo.yaml", "--rate", "0", "--wait-for", "recorder/main"]
    assert player.cwd == REPO
    assert set(player.depends_on) == {"router", "recorder"}


def test_repo_compose_overrides(tmp_path: Path) -> None:
    env = {"FIXSTREAM_SCENARIO": "/tmp/s.yaml", "FIXSTREAM_RATE": "5", "FIXSTREAM_ZENOH_CONNECT": "tcp/elsewhere:1"}
    project = load_compose(REPO / "compose.yaml", environ=env, overrides={"FIXSTREAM_RECORDINGS": str(tmp_path)})
    plan = plan_stack(project, project.select(["player"]), environ=env, stop_timeout=3, create_dirs=False)
    procs = {p.service: p for p in plan.processes}
    assert list(procs) == ["router", "recorder", "player"]  # dependencies come along
    assert procs["player"].argv[-5:-2] == ["/tmp/s.yaml", "--rate", "5"]
    assert procs["recorder"].env["FIXSTREAM_RECORDER_OUT_DIR"] == str(tmp_path)
    assert procs["recorder"].stop_timeout == 3  # --timeout overrides stop_grace_period
    # the host's own Zenoh endpoint does not leak into the stack
    assert procs["player"].env["FIXSTREAM_ZENOH_CONNECT"] == plan.endpoint


def test_start_order_and_selection(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        """
services:
  c: {command: [c], depends_on: [b]}
  a: {command: [a]}
  b: {command: [b], depends_on: {a: {condition: service_completed_successfully}}}
  d: {command: [d]}
  e: {command: [e], profiles: [extra]}
""",
    )
    project = load_compose(path, environ={})
    assert project.start_order() == ["a", "b", "c", "d", "e"]
    assert project.select() == ["a", "b", "c", "d"]
    assert project.select(profiles=["extra"]) == ["a", "b", "c", "d", "e"]
    assert project.select(["c"]) == ["a", "b", "c"]
    assert project.select(["e"]) == ["e"]
    assert project.services["b"].depends_on == {"a": "service_completed_successfully"}
    with pytest.raises(ComposeError, match="no such service"):
        project.select(["nope"])


def test_cycles_and_unknown_dependencies(tmp_path: Path) -> None:
    cyclic = load_compose(write(tmp_path, "services:\n  a: {depends_on: [b]}\n  b: {depends_on: [a]}\n"), environ={})
    with pytest.raises(ComposeError, match="cycle"):
        cyclic.start_order()
    with pytest.raises(ComposeError, match="undefined service"):
        load_compose(write(tmp_path, "services:\n  a: {depends_on: [ghost]}\n", "other.yaml"), environ={})


def test_environment_forms_volumes_and_paths(tmp_path: Path) -> None:
    (tmp_path / "svc.env").write_text("FROM_FILE=${GREETING}\nOVERRIDDEN=file\n")
    path = write(
        tmp_path,
        """
services:
  router:
    image: docker.io/eclipse/zenoh:1.10.2
    command: -l tcp/0.0.0.0:7448 --no-multicast-scouting
  app:
    command: python /scripts/app.py --out=/data/out/x.mcap /data/outside /data/out
    entrypoint: [python3]
    working_dir: /scripts
    env_file: svc.env
    environment:
      - ROUTER=tcp/router:7448
      - NOT_ROUTER=tcp/router:9999
      - OUT=/data/out/sub
      - OVERRIDDEN=env
      - PASSED
      - ABSENT
    volumes:
      - ./out:/data/out
      - type: bind
        source: ./scripts
        target: /scripts
        read_only: true
      - cache:/cache
    stop_signal: SIGINT
    stop_grace_period: 1m30s
volumes:
  cache: {}
""",
    )
    (tmp_path / "scripts").mkdir()
    env = {"GREETING": "hi", "PASSED": "through"}
    project = load_compose(path, environ=env)
    plan = plan_stack(project, project.select(), environ=env)
    try:
        app = plan.processes[1]
        port = plan.processes[0].router_port
        out = tmp_path / "out"
        assert out.is_dir()  # bind sources are created like compose does
        assert app.argv == [
            sys.executable,  # entrypoint python3 -> this interpreter
            "python",  # only argv[0] is resolved
            str(tmp_path / "scripts" / "app.py"),
            f"--out={out}/x.mcap",
            "/data/outside",  # not under a mount target
            str(out),
        ]
        assert app.cwd == tmp_path / "scripts"
        assert app.env["ROUTER"] == f"tcp/127.0.0.1:{port}"
        assert app.env["NOT_ROUTER"] == "tcp/router:9999"  # not a port the router listens on
        assert app.env["OUT"] == f"{out}/sub"
        assert app.env["FROM_FILE"] == "hi"
        assert app.env["OVERRIDDEN"] == "env"
        assert app.env["PASSED"] == "through"
        assert "ABSENT" not in app.env
        assert app.stop_signal == signal.SIGINT
        assert app.stop_timeout == 90.0
        assert plan.output_dirs[0] == out and len(plan.output_dirs) == 2  # ./out and the named volume
        assert plan.temp_dirs and plan.temp_dirs[0].is_dir()
    finally:
        for d in plan.temp_dirs:
            d.rmdir()


def test_required_variable_missing_names_the_service(tmp_path: Path) -> None:
    path = write(tmp_path, "services:\n  a:\n    command: [x, '${NEED:?set NEED to run a}']\n")
    with pytest.raises(ComposeError, match=r"services\.a\.command\[1\].*set NEED to run a"):
        load_compose(path, environ={})


def test_dotenv_and_env_file_precedence(tmp_path: Path) -> None:
    path = write(tmp_path, "services:\n  a:\n    command: [x, '${A}', '${B}', '${C:-none}']\n")
    (tmp_path / ".env").write_text("A=dotenv\nB=dotenv\n")
    (tmp_path / "alt.env").write_text("C=alt\n")
    assert load_compose(path, environ={"B": "shell"}).services["a"].command == ["x", "dotenv", "shell", "none"]
    alt = load_compose(path, env_file=tmp_path / "alt.env", environ={}, overrides={"A": "cli"})
    assert alt.services["a"].command == ["x", "cli", "", "alt"]
    assert any("B variable is not set" in w for w in alt.warnings)


def test_durations_and_find(tmp_path: Path) -> None:
    assert parse_duration("10s") == 10 and parse_duration("1m30s") == 90 and parse_duration("500ms") == 0.5
    assert parse_duration(3) == 3 and parse_duration("2") == 2
    with pytest.raises(ComposeError):
        parse_duration("10 parsecs")
    nested = tmp_path / "a" / "b"
    nested.mkdir(parents=True)
    path = write(tmp_path, "services: {}\n")
    assert find_compose_file(nested) == path
