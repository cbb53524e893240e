"""``fixstream report`` on a real demo recording (issue 8).

* The demo stack (the repository's compose.yaml through ``fixstream up``, every estimator of the demo) plays
  ``scenarios/demo.yaml`` as Monte-Carlo run 0 of its seed (``fixstream play --run 0``: the compose file is copied
  with that one argument added to the player's command, and every service run from the repository); the
  attitude service attaches its raw-baseline angles (``FIXSTREAM_ATTITUDE_RAW_OUTPUT``) as the mc plugin's run
  does. The report of that recording:
  - has, per estimator of the scenario, the metrics ``fixstream mc --runs 1`` computes for the same scenario and
    seed — equal, key for key and number for number (except the keys the plugin marks ``OFFLINE_ONLY``: the
    core's internal counters, which nothing published carries);
  - has a summary with a verdict per estimator against its paper's figures (issue 17: what the figure is in words,
    the paper's number and this run's), plan views, errors and NEES per estimator;
  - renders in headless Chromium with no console message at all (the page has no script; any message is an
    error), and its screenshot is a plausible page: full size, many colours, not one colour mostly;
  - copied to an empty directory, the recording gives the same metrics.json (issue 17) when the recorder
    attached the scenario to it;
* the console check itself catches a page with a script error (so the check above can fail);
* ``fixstream up --report`` (what ``make demo`` runs) ends by writing that report and printing its path.
"""

from __future__ import annotations

import html
import importlib
import json
import os
import re
import shutil
import subprocess
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO, fixstream_cmd

from tools.report.paper import paper_figures

pytestmark = pytest.mark.e2e

DEMO = REPO / "scenarios" / "demo.yaml"
SEED = 1
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--hide-scrollbars",
    "--enable-logging=stderr",
    "--v=0",
]
WINDOW = (1200, 3000)


def chromium() -> str:
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    assert path, "Debian's chromium is needed to render the report: `make tools` installs it (apt-get install chromium)"
    return path


def render(page: Path, tmp: Path, name: str = "shot") -> tuple[list[str], Path]:
    """Open the page in headless Chromium: (console lines, screenshot)."""
    shot = tmp / f"{name}.png"
    done = subprocess.run(
        [
            chromium(),
            *CHROMIUM_FLAGS,
            f"--user-data-dir={tmp / (name + '-profile')}",
            f"--window-size={WINDOW[0]},{WINDOW[1]}",
            f"--screenshot={shot}",
            page.resolve().as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    console = [line for line in done.stderr.splitlines() if re.search(r":CONSOLE[:(]", line)]
    return console, shot


def assert_plausible_screenshot(shot: Path) -> None:
    from PIL import Image

    assert shot.is_file() and shot.stat().st_size > 20_000, "screenshot missing or tiny"
    with Image.open(shot) as img:
        assert img.size == WINDOW
        px = np.asarray(img.convert("RGB")).reshape(-1, 3)
    _, counts = np.unique(px, axis=0, return_counts=True)
    top_share = counts.max() / len(px)
    assert top_share < 0.95, f"{top_share:.1%} of the screenshot is one colour"
    assert len(counts) > 200, f"only {len(counts)} colours in the screenshot"


def demo_compose(tmp_path: Path) -> Path:
    """The repository's compose.yaml, services run from the repository, the player playing mc run 0."""
    doc = yaml.safe_load((REPO / "compose.yaml").read_text())
    doc = {k: v for k, v in doc.items() if not k.startswith("x-")}
    for name, svc in doc["services"].items():
        if str(svc.get("image", "")).startswith("eclipse/zenoh"):
            continue
        svc["working_dir"] = str(REPO)
        if name == "player":
            svc["command"] = [*svc["command"], "--run", "0"]
    path = tmp_path / "compose.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Run the demo stack once (run 0 of the demo's seed), then report it and run ``fixstream mc`` on it."""
    tmp = tmp_path_factory.mktemp("demo")
    env = {k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_")}
    env.update({"FIXSTREAM_SCENARIO": str(DEMO), "FIXSTREAM_RATE": "0", "FIXSTREAM_ATTITUDE_RAW_OUTPUT": "true"})
    recordings = tmp / "recordings"
    up = subprocess.run(
        fixstream_cmd("up", "-f", str(demo_compose(tmp)), "--recordings", str(recordings), "--no-color", "--report"),
        cwd=tmp,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert up.returncode == 0, (up.stdout + up.stderr)[-5000:]
    # `make demo` = `fixstream up --report`: the run ends with the report of its recording and prints where it is
    (recording,) = sorted(recordings.glob("*.mcap"))
    demo_page = recording.parent / f"{recording.stem}_report" / "index.html"
    assert f"[up] report: {demo_page}" in up.stdout and demo_page.is_file(), up.stdout[-3000:]
    report = subprocess.run(
        fixstream_cmd("report", str(recordings), "--out", str(tmp / "report"), "--no-progress"),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert report.returncode == 0, report.stderr[-3000:]
    assert f"report: {tmp / 'report' / 'index.html'}" in report.stdout
    mc = subprocess.run(
        fixstream_cmd(
            "mc",
            str(DEMO),
            "--runs",
            "1",
            "--seed",
            str(SEED),
            "--workers",
            "1",
            "--no-progress",
            "--out",
            str(tmp / "mc.json"),
        ),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert mc.returncode == 0, mc.stderr[-3000:]
    return {
        "dir": tmp,
        "html": tmp / "report" / "index.html",
        "metrics": tmp / "report" / "metrics.json",
        "mc": tmp / "mc.json",
    }


def test_report_metrics_equal_fixstream_mc(demo_run: dict[str, Path]) -> None:
    report = json.loads(demo_run["metrics"].read_text())
    mc = json.loads(demo_run["mc"].read_text())
    assert report["run"]["scenario"] == "demo" and report["run"]["seed"] == SEED
    expected = mc["per_run"][0]["estimators"]
    assert set(report["estimators"]) == set(expected) >= {"tan1", "rx1-fm", "rx1-dvbt", "r1"}
    for instance, entry in report["estimators"].items():
        assert entry["status"] == "ok", (instance, entry)
        plugin = importlib.import_module(f"services.{entry['kind']}.mc")
        offline_only = set(plugin.OFFLINE_ONLY)
        assert offline_only == set(entry["offline_only"])
        want = {k: v for k, v in expected[instance].items() if k not in offline_only}
        got = entry["metrics"]
        assert set(got) == set(want), (instance, set(got) ^ set(want))
        for key in want:
            assert got[key] == want[key], f"{instance}: {key} differs"
    # the run had something to score: fixes, tracks and angle errors
    assert expected["tan1"]["n_fixes"] > 0
    assert expected["rx1-fm"]["n_confirmed_tracks"] > 0
    assert any(v is not None for v in expected["r1"]["targets"]["jet1"]["raw_err"]["psi_los"])


def test_report_has_a_section_per_estimator_and_the_papers_figures(demo_run: dict[str, Path]) -> None:
    report = json.loads(demo_run["metrics"].read_text())
    kinds = Counter(s["kind"] for s in report["sections"])
    assert kinds["terrain_nav"] == 1 and kinds["pcl_tracker"] == 2 and kinds["attitude"] == 1
    # a section for every estimator that published (services added to the stack later get one too)
    services = {src.split("/", 1)[0] for src in report["run"]["publishers"]}
    assert services - {"recorder", "coordinator"} <= set(kinds), (services, kinds)
    page = html.unescape(demo_run["html"].read_text())
    assert page.count("data:image/png;base64,") >= 4 * 4  # plan, error, NEES, story per estimator
    for figure in ("≤ 1 cell", "< 50 m", "units of degrees"):  # the digests' figures in the summary
        assert figure in page
    assert "http://" not in page and "https://" not in page  # nothing to fetch: opens offline
    # a verdict per estimator against its paper, the figure in words (its digest section only in metrics.json)
    verdicts = report["verdicts"]
    with_paper = {(s["kind"], s["instance"]) for s in report["sections"] if s["kind"] in paper_figures()}
    assert {(v["kind"], v["instance"]) for v in verdicts} == with_paper
    assert {v["verdict"] for v in verdicts} <= {"pass", "outside", "not comparable", "no data"}
    summary = page[page.index("id='summary'") : page.index("id='s0'")]
    assert "digest 00" not in summary and summary.count("class='verdict ") == len(verdicts)


def test_the_demo_recording_reports_the_same_from_an_empty_directory(demo_run: dict[str, Path]) -> None:
    """Issue 17's acceptance: the recording copied to an empty directory and reported there (nothing but the file:
    no repository, no scenarios directory) gives the metrics.json of the report made in the repository."""
    from tools.report.carried import read_carried

    (recording,) = sorted((demo_run["dir"] / "recordings").glob("*.mcap"))
    # issue 17 item 3: the recorder attaches the scenario the run played
    assert read_carried([recording]).scenarios, "the demo recording carries no scenario attachment"
    empty = demo_run["dir"] / "empty"
    empty.mkdir()
    copy = Path(shutil.copy2(recording, empty / recording.name))
    done = subprocess.run(
        fixstream_cmd("report", copy.name, "--out", "report", "--no-progress"),
        cwd=empty,
        env={k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_")},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert sorted(p.name for p in empty.iterdir()) == sorted([copy.name, "report"])
    assert (empty / "report" / "metrics.json").read_text() == demo_run["metrics"].read_text()
    away = json.loads((empty / "report" / "metrics.json").read_text())
    assert away["run"]["scenario_file"].endswith("(attached to the recording)")
    assert all(entry["status"] == "ok" for entry in away["estimators"].values())


def test_report_renders_in_headless_chromium(demo_run: dict[str, Path]) -> None:
    console, shot = render(demo_run["html"], demo_run["dir"])
    assert console == [], "console messages:\n" + "\n".join(console)
    assert_plausible_screenshot(shot)


def test_the_console_check_catches_a_script_error(tmp_path: Path) -> None:
    page = tmp_path / "broken.html"
    page.write_text("<!DOCTYPE html><html><body><p>x</p><script>notDefinedAnywhere();</script></body></html>")
    console, _ = render(page, tmp_path, "broken")
    assert any("notDefinedAnywhere" in line for line in console), console
