"""The report's LBL and group-navigation sections on recordings built from their cores (issue 8).

Their services and player plugins are being written; until then a recording of each is made in-process
(:mod:`tools.report.offline`: the digest's S2 LBL run and the group's fleet run with the coordinator core in
the loop, written with the recorder's writer, publishers named as the services will be). The sections' headline
numbers are checked against the cores' own evaluation code on the same runs (``services.lbl_nav.offline``,
``services.rd_nav.offline``), which shares nothing with the report; the page renders in headless Chromium.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from test_report import assert_plausible_screenshot, render

from services.lbl_nav import simulation as lbl_sim
from services.lbl_nav.offline import run_core as lbl_run_core
from services.lbl_nav.offline import scenario_config
from tools.report import make_report
from tools.report.offline import lbl_items, marker, rd_items, write_recording

RD_SECONDS = 900.0


def sig3(x: float) -> float:
    """``x`` as the report's headline gives it: three significant digits."""
    return float(f"{float(x):.3g}")


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    tmp = tmp_path_factory.mktemp("sections")
    lbl = lbl_items(seed=3, platform="lbl1")  # the group's vehicles are auv1...auv7
    rd = rd_items(seed=2, duration_s=RD_SECONDS)
    files = write_recording(tmp / "rec", [("fixstream/scenario/offline", marker("offline", "start", 0, 0))], lbl, rd)
    result = make_report(files, tmp / "out", progress=False)
    return {"tmp": tmp, "result": result, "metrics": json.loads(result.metrics_path.read_text())}


def section(metrics: dict, kind: str) -> dict:  # type: ignore[type-arg]
    (found,) = [s for s in metrics["sections"] if s["kind"] == kind]
    return found["headline"]  # type: ignore[no-any-return]


def test_lbl_section_matches_the_cores_own_trace(report: dict) -> None:  # type: ignore[type-arg]
    head = section(report["metrics"], "lbl_nav")
    spec = lbl_sim.s2_spec()
    sim = lbl_sim.simulate(spec, np.random.default_rng(3), 3)
    trace = lbl_run_core(scenario_config(spec.name), sim)
    assert trace.resolution_t_s is not None and not trace.merged
    assert head["resolution_after_launch_s"] == pytest.approx(trace.resolution_t_s, abs=1e-9)
    assert head["decision_correct"] is (not trace.wrong)
    assert head["decision"].startswith("resolved")
    after = (trace.t_s >= trace.resolution_t_s) & np.all(np.isfinite(trace.pos), axis=1)
    err = trace.pos[after] - trace.truth[after]
    rms = math.sqrt(float(np.mean(np.sum(err * err, axis=1))))
    assert head["horizontal_rms_after_resolution_m"] == pytest.approx(sig3(rms))
    assert head["epochs"] == len(trace.t_s) + trace.fixes_pre_launch
    assert 0.0 <= head["nees_in_95_band"] <= 1.0 and head["nees_dof"] == 2


def test_rd_section_matches_the_in_process_run(report: dict) -> None:  # type: ignore[type-arg]
    from services.coordinator.config import CoordinatorConfig
    from services.coordinator.core import CoordinatorCore
    from services.rd_nav import simulation
    from services.rd_nav.offline import run

    head = section(report["metrics"], "rd_nav")
    log = run(simulation.fleet(duration_s=RD_SECONDS), 2, coordinator=CoordinatorCore(CoordinatorConfig()))
    moving = {auv: a for auv, a in log.auv.items() if a.pf}
    assert set(head["per_auv"]) == set(moving) and moving
    for auv, a in moving.items():
        rows = np.array(a.pf)
        e_north, e_east = rows[:, 1] - rows[:, 6], rows[:, 2] - rows[:, 7]
        got = head["per_auv"][auv]
        assert got["cycle_fixes"] == len(rows)
        assert got["error_mean_m"] == pytest.approx([sig3(e_east.mean()), sig3(e_north.mean())])
        assert got["error_max_abs_m"] == pytest.approx(sig3(max(np.abs(e_east).max(), np.abs(e_north).max())))
        assert sum(got["cycles"].values()) == len(rows)
    assignments = [m for m in log.coordinator_out if type(m).__name__ == "BeaconAssignment"]
    assert head["assignments"] == len(assignments) and head["role_changes"] >= 1


def test_sections_have_their_figures_and_the_page_renders(report: dict) -> None:  # type: ignore[type-arg]
    page = report["result"].html_path.read_text()
    for title in ("Hypotheses, probabilities and resolution", "Beacon roles and cycle status", "NEES", "Plan view"):
        assert title in page
    assert page.count("data:image/png;base64,") == 8  # plan, error, NEES, story for each
    assert any("no scenario" in n or "not found" in n for n in report["metrics"]["notes"])
    console, shot = render(report["result"].html_path, Path(report["tmp"]), "sections")
    assert console == [], console
    assert_plausible_screenshot(shot)
