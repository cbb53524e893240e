"""``fixstream up`` with real processes: compose files in tmp_path, the embedded router from the Zenoh image
service, and small probe services (python scripts reached through a bind volume)."""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import textwrap
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import REPO, fixstream_cmd, wait_until

from tools.stack import Supervisor, load_compose, plan_stack
from tools.stack.console import Console

PROBE = """
import json, os, signal, sys, time

name, mode = sys.argv[1], sys.argv[2]
out = os.environ["OUT"]


def record(event, **extra):
    with open(os.path.join(out, "events.jsonl"), "a") as f:
        f.write(json.dumps({"name": name, "event": event, "t": time.time(), **extra}) + "\\n")


def on_term(signum, frame):
    record("sigterm")
    sys.exit(int(os.environ.get("T_TERM_CODE", "0")))


signal.signal(signal.SIGTERM, on_term)
env = {k: v for k, v in os.environ.items() if k.startswith(("FIXSTREAM_ZENOH_", "T_", "OUT"))}
record("start", env=env, argv=sys.argv[1:], cwd=os.getcwd())
print(f"probe {name} up", flush=True)
if mode == "alive":  # join Zenoh as configured, declare a liveliness token a bit later, serve
    time.sleep(0.5)
    from shared.session import open_session

    session = open_session()
    token = session.liveliness().declare_token(f"fixstream/alive/probe/{name}")
    record("alive")
elif mode == "exit":
    time.sleep(float(sys.argv[3]))
    record("exit")
    sys.exit(int(sys.argv[4]))
elif mode == "stubborn":
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
while True:
    time.sleep(0.05)
"""

ROUTER = """
router:
  image: eclipse/zenoh:1.10.2
  command: ["--listen", "tcp/0.0.0.0:7447", "--no-multicast-scouting"]
"""


def project_dir(tmp_path: Path, services: str, dotenv: str = "") -> Path:
    (tmp_path / "scripts").mkdir()
    (tmp_path / "scripts" / "probe.py").write_text(PROBE)
    compose = "x-probe: &probe\n  volumes: ['./out:/data/out', './scripts:/app/scripts:ro']\n"
    compose += "  environment: &probe-env\n    OUT: /data/out\n"
    compose += "services:\n" + textwrap.indent(textwrap.dedent(services).strip("\n"), "  ") + "\n"
    compose = compose.replace("  ROUTER\n", textwrap.indent(ROUTER.strip("\n") + "\n", "  "))
    (tmp_path / "compose.yaml").write_text(compose)
    if dotenv:
        (tmp_path / ".env").write_text(dotenv)
    return tmp_path


def events(root: Path) -> list[dict[str, Any]]:
    path = root / "out" / "events.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def first(evs: list[dict[str, Any]], name: str, event: str) -> dict[str, Any]:
    return next(e for e in evs if e["name"] == name and e["event"] == event)


def run_stack(root: Path, **kwargs: Any) -> tuple[Any, str]:
    env = dict(os.environ)
    project = load_compose(root / "compose.yaml", environ=env)
    plan = plan_stack(project, project.select(), environ=env, stop_timeout=kwargs.pop("stop_timeout", 5.0))
    out = io.StringIO()
    result = Supervisor(plan, Console(out, color=False), **kwargs).run()
    return result, out.getvalue()


def test_up_runs_compose_in_order_with_env_volumes_and_driver_shutdown(tmp_path: Path) -> None:
    """Through the CLI: router replaced, readiness by liveliness, interpolation, paths, SIGTERM on driver exit."""
    root = project_dir(
        tmp_path,
        """
        ROUTER
        server:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "server", "alive"]
          environment:
            <<: *probe-env
            FIXSTREAM_ZENOH_CONNECT: tcp/router:7447
            T_SHELL_WINS: ${T_SHELL_WINS:-compose default}
            T_FROM_DOTENV: ${T_FROM_DOTENV}
            T_DEFAULT: ${T_UNSET_FOR_TEST:-fallback}
            T_ESCAPED: $$NOT_A_VAR
          labels:
            fixstream.alive: fixstream/alive/probe/server
          depends_on: [router]
        driver:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "driver", "exit", "0.2", "0", "/data/out/result.txt"]
          depends_on: [server]
          labels:
            fixstream.role: driver
        """,
        dotenv="T_FROM_DOTENV=from dotenv\nT_SHELL_WINS=from dotenv\n",
    )
    env = {**os.environ, "T_SHELL_WINS": "from shell"}
    env.pop("T_UNSET_FOR_TEST", None)
    proc = subprocess.run(
        fixstream_cmd("up", "--no-color", "--drain", "0.2", "--timeout", "5"),
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = proc.stdout
    evs = events(root)
    server_start, driver_start = first(evs, "server", "start"), first(evs, "driver", "start")
    # start order: the driver only started once the server's liveliness token was up
    assert first(evs, "server", "alive")["t"] <= driver_start["t"]
    assert "[up] server ready: fixstream/alive/probe/server" in out
    assert out.index("[up] router started") < out.index("[up] server started") < out.index("[up] driver started")
    # the Zenoh endpoint points at the embedded loopback router (the server joined through it)
    connect = server_start["env"]["FIXSTREAM_ZENOH_CONNECT"]
    assert connect.startswith("tcp/127.0.0.1:") and f"embedded router on {connect}" in out
    assert driver_start["env"]["FIXSTREAM_ZENOH_CONNECT"] == connect
    # interpolation as compose: shell over .env, defaults, $$ escape
    assert server_start["env"]["T_SHELL_WINS"] == "from shell"
    assert server_start["env"]["T_FROM_DOTENV"] == "from dotenv"
    assert server_start["env"]["T_DEFAULT"] == "fallback"
    assert server_start["env"]["T_ESCAPED"] == "$NOT_A_VAR"
    # container paths of bind volumes mapped to host paths, in env values and arguments
    assert server_start["env"]["OUT"] == str(root / "out")
    assert driver_start["argv"][-1] == str(root / "out" / "result.txt")
    # driver exit stopped the rest with SIGTERM, in reverse start order, router last
    assert any(e["name"] == "server" and e["event"] == "sigterm" for e in evs)
    assert out.index("stopping server (SIGTERM)") < out.index("stopping router (SIGTERM)")
    assert "router exited with code 0" in out and "server exited with code 0" in out
    # output lines carry the service prefix
    assert "server   | probe server up" in out and "driver   | probe driver up" in out


def test_failing_service_stops_the_stack_with_nonzero_exit(tmp_path: Path) -> None:
    root = project_dir(
        tmp_path,
        """
        crasher:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "crasher", "exit", "1.0", "3"]
        bystander:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "bystander", "serve"]
        driver:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "driver", "serve"]
          labels: {fixstream.role: driver}
        """,
    )
    t0 = time.monotonic()
    result, out = run_stack(root)
    assert time.monotonic() - t0 < 20
    assert result.exit_code == 1
    assert result.returncodes["crasher"] == 3
    assert result.returncodes["driver"] == 0 and result.returncodes["bystander"] == 0  # stopped, handled SIGTERM
    assert any("crasher: exited with code 3" in f for f in result.failures)
    assert "a service failed, stopping the stack" in out
    evs = events(root)
    stops = [e["name"] for e in evs if e["event"] == "sigterm"]
    assert stops == ["driver", "bystander"]  # reverse start order


def test_driver_exit_code_is_the_stack_exit_code(tmp_path: Path) -> None:
    root = project_dir(
        tmp_path,
        """
        worker:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "worker", "serve"]
        driver:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "driver", "exit", "1.0", "4"]
          depends_on: [worker]
          labels: {fixstream.role: driver}
        """,
    )
    result, out = run_stack(root, drain=0)
    assert result.exit_code == 4
    assert result.returncodes["worker"] == 0
    assert "driver exited with code 4" in out and "stopping worker (SIGTERM)" in out


def test_stubborn_service_is_killed_after_the_timeout(tmp_path: Path) -> None:
    root = project_dir(
        tmp_path,
        """
        stubborn:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "stubborn", "stubborn"]
          stop_grace_period: 30s
        driver:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "driver", "exit", "1.0", "0"]
          labels: {fixstream.role: driver}
        """,
    )
    t0 = time.monotonic()
    result, out = run_stack(root, drain=0, stop_timeout=1.0)
    assert time.monotonic() - t0 < 15
    assert result.returncodes["stubborn"] == -signal.SIGKILL
    assert result.exit_code == 1
    assert any("stubborn: did not stop within 1 s" in f for f in result.failures)
    assert "stubborn: did not stop within 1 s, SIGKILL" in out


def test_dependency_that_never_becomes_ready_fails_the_run(tmp_path: Path) -> None:
    root = project_dir(
        tmp_path,
        """
        ROUTER
        silent:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "silent", "serve"]
          labels: {fixstream.alive: fixstream/alive/probe/silent}
          depends_on: [router]
        dependent:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "dependent", "serve"]
          depends_on: [silent]
        """,
    )
    result, out = run_stack(root, ready_timeout=2.0)
    assert result.exit_code == 1
    assert "[up] silent started" in out and "dependent started" not in out
    assert result.start_order == ["router", "silent"]
    assert any(
        "dependent: dependencies not ready after 2 s: silent (liveliness fixstream/alive/probe/silent)" in f
        for f in result.failures
    ), result.failures
    assert result.returncodes["silent"] == 0 and result.returncodes["router"] == 0  # stopped cleanly


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=lambda s: s.name)
def test_completed_dependency_and_sigterm_to_the_runner(tmp_path: Path, sig: signal.Signals) -> None:
    """A one-shot init must finish first; SIGTERM to ``fixstream up`` stops everything in reverse order
    and the exit code says so (not the interrupted driver's code). SIGHUP (the terminal closed, an ssh session
    dropped) does the same: it once ended ``up`` alone and left the whole stack running, orphaned."""
    root = project_dir(
        tmp_path,
        """
        init:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "init", "exit", "0.3", "0"]
        first:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "first", "serve"]
          depends_on:
            init: {condition: service_completed_successfully}
        second:
          <<: *probe
          command: ["python", "/app/scripts/probe.py", "second", "serve"]
          environment:
            <<: *probe-env
            T_TERM_CODE: "1"  # an interrupted driver may say so
          depends_on: [first]
          labels: {fixstream.role: driver}
        """,
    )
    proc = subprocess.Popen(
        fixstream_cmd("up", "--no-color"), cwd=root, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        assert wait_until(lambda: {"first", "second"} <= {e["name"] for e in events(root)}, timeout=20)
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + sig, out
    evs = events(root)
    assert first(evs, "init", "exit")["t"] <= first(evs, "first", "start")["t"]
    assert [e["name"] for e in evs if e["event"] == "sigterm"] == ["second", "first"]  # the services get SIGTERM
    assert f"{sig.name} received, stopping the stack" in out
    assert "second exited with code 1" in out and "failed:" not in out


def test_dry_run_prints_the_local_commands() -> None:
    proc = subprocess.run(
        fixstream_cmd("up", "--dry-run", "--no-color", "-f", str(REPO / "compose.yaml")),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert "router: cd" in proc.stdout and " router --listen tcp/127.0.0.1:" in proc.stdout
    assert "tools.cli.main run recorder" in proc.stdout and "FIXSTREAM_RECORDER_OUT_DIR=" in proc.stdout


@pytest.mark.parametrize("bad", ["services:\n  a:\n    command: ['${NEED:?please set NEED}']\n", "services: 3\n"])
def test_bad_compose_file_exits_2(tmp_path: Path, bad: str) -> None:
    (tmp_path / "compose.yaml").write_text(bad)
    proc = subprocess.run(fixstream_cmd("up"), cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "[up] error:" in proc.stdout
