"""``fixstream mc --scheduler``: the runs on a Dask distributed cluster give the local pool's JSON (issue 18, item 6).

The cluster is a ``distributed.LocalCluster`` on loopback with its workers as threads of this process
(``processes=False``: no process start-up, the test stays fast); ``fixstream mc`` runs as a separate process and
reaches the scheduler over TCP, as it would a remote cluster.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import fixstream_cmd
from test_scenario_files import REPO, nav_scenario, write_scenario

from services.player.scenario import load_scenario
from tools import montecarlo

distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def scheduler() -> Iterator[str]:
    with distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=False,
        protocol="tcp",
        host="127.0.0.1",
        dashboard_address=None,
    ) as cluster:
        yield str(cluster.scheduler_address)


def _mc(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(fixstream_cmd("mc", *args), capture_output=True, text=True, cwd=REPO, timeout=300)


@pytest.mark.parametrize("name", ["nav", "lbl_nav_demo"])
def test_runs_on_a_dask_cluster_give_the_local_json(name: str, scheduler: str, tmp_path: Path) -> None:
    """Byte-identical JSON (per-run and aggregate) to the in-process pool for the same seed: sensor statistics only
    (nav), and an estimator's mc plugin (lbl_nav_demo)."""
    if name == "nav":
        path = write_scenario(tmp_path, nav_scenario(name="mcdask", duration_s=10.0))
    else:
        path = REPO / "scenarios" / f"{name}.yaml"
    runs = 3
    local = montecarlo.dumps(montecarlo.run_montecarlo(load_scenario(path), runs, seed=9, workers=1, progress=False))
    out = tmp_path / "dask.json"
    proc = _mc(str(path), "--runs", str(runs), "--seed", "9", "--out", str(out), "--scheduler", scheduler, "--progress")
    assert proc.returncode == 0, proc.stderr
    assert out.read_text() == local
    assert f"{runs}/{runs}" in proc.stderr  # the progress bar, as for local runs (asked for: not a terminal here)
    assert f"on the Dask cluster at {scheduler}" in proc.stderr


def test_without_dask_the_scheduler_option_fails_with_one_line_and_exit_2(tmp_path: Path) -> None:
    path = write_scenario(tmp_path, nav_scenario(name="nodask", duration_s=2.0))
    hide = "import sys; sys.modules['distributed'] = None; from tools.cli.main import main; sys.exit(main())"
    argv = ["mc", str(path), "--runs", "2", "--out", str(tmp_path / "x.json"), "--scheduler", "tcp://127.0.0.1:9"]
    proc = subprocess.run([sys.executable, "-c", hide, *argv], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert lines == [lines[0]] and "dask.distributed" in lines[0] and "not installed" in lines[0], proc.stderr
    assert not (tmp_path / "x.json").exists()


def test_an_unreachable_scheduler_is_one_clear_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from shared.session import free_tcp_port

    monkeypatch.setattr(montecarlo, "DASK_CONNECT_TIMEOUT_S", 1.0)
    scenario = load_scenario(write_scenario(tmp_path, nav_scenario(name="noscheduler", duration_s=2.0)))
    address = f"tcp://127.0.0.1:{free_tcp_port()}"
    with pytest.raises(montecarlo.DaskUnavailable, match="no Dask scheduler reachable at"):
        montecarlo.run_montecarlo(scenario, 2, seed=1, progress=False, scheduler=address)


def test_workers_and_scheduler_exclude_each_other(tmp_path: Path) -> None:
    path = write_scenario(tmp_path, nav_scenario(name="both", duration_s=2.0))
    proc = _mc(
        str(path), "--runs", "2", "--out", str(tmp_path / "x.json"), "--workers", "2", "--scheduler", "tcp://h:1"
    )
    assert proc.returncode == 2 and "--workers" in proc.stderr
