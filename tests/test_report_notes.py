"""What the report tells a reader beyond the figures (a new user's audit): a run cut short says so, and the LBL
"which hypothesis" verdict says why it has no data when the decision came at once."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from schemas import Header, ScenarioMarker, Truth
from shared.events import Event
from tools.report.data import cut_short, find_scenario
from tools.report.paper import _lbl_decision
from tools.report.reading import Recording

NS = 1_000_000_000


def marker(event: Literal["start", "end"], t_s: float, source: str = "player/main", scenario: str = "demo") -> Event:
    msg = ScenarioMarker(header=Header(stamp_ns=int(t_s * NS), source=source), event=event, scenario=scenario, seed=1)
    return Event(msg.header.stamp_ns, f"fixstream/scenario/{scenario}", msg)


def truth(t_s: float) -> Event:
    msg = Truth(
        header=Header(stamp_ns=int(t_s * NS), source="player/main"), platform="auv1", position_m=[0.0, 0.0, 0.0]
    )
    return Event(msg.header.stamp_ns, "fixstream/truth/auv1", msg)


def test_a_recording_without_its_end_marker_is_reported_as_cut_short() -> None:
    rec = Recording(files=[Path("x.mcap")], items=[marker("start", 0.0), truth(10.0), truth(30.9)])
    note = cut_short(rec, None)
    assert note is not None and "cut short" in note and "30.9 s" in note


def test_a_run_that_ended_or_a_second_run_that_ended_is_not() -> None:
    ended = [marker("start", 0.0), truth(30.0), marker("end", 60.0)]
    assert cut_short(Recording(files=[], items=ended), None) is None
    assert (
        cut_short(Recording(files=[], items=[*ended, marker("start", 61.0), truth(62.0), marker("end", 90.0)]), None)
        is None
    )
    assert cut_short(Recording(files=[], items=[*ended, marker("start", 61.0), truth(62.0)]), None) is not None
    assert cut_short(Recording(files=[], items=[truth(1.0)]), None) is None  # no scenario: nothing to compare with


def test_the_lbl_decision_verdict_gives_the_reason_it_has_no_data() -> None:
    head = {
        "decision": "resolved (hypothesis 1)",
        "decision_correct": None,
        "decision_note": "resolved at once: no pair",
    }
    ((_, _, _, note),) = list(_lbl_decision(head, None))
    assert note == "resolved at once: no pair"
    ((_, _, verdict, _),) = list(_lbl_decision({**head, "decision_correct": True}, None))
    assert verdict != "no data" and verdict


def test_only_a_players_markers_name_runs_and_the_scenario() -> None:
    """A new user's audit: a report said a recording of 8 runs held 25, counting the start markers a non-player
    source had sent; such a marker must not name the scenario, nor leave a run looking cut short, either."""
    stray = [marker("start", 5.0, source="evil", scenario="other"), marker("start", 70.0, source="", scenario="x")]
    runs = [marker("start", 0.0), truth(30.0), marker("end", 60.0), marker("start", 61.0), marker("end", 90.0)]
    rec = Recording(files=[], items=[stray[0], *runs, stray[1]])
    assert [m.scenario for _, m in rec.markers] == ["demo"] * 4
    assert cut_short(rec, None) is None
    choice = find_scenario(rec, None, scenarios_dir=None)
    assert choice.name == "demo" and any("holds 2 scenario runs" in n for n in choice.notes), choice.notes


def test_an_estimator_of_the_scenario_that_published_nothing_is_named_not_dropped() -> None:
    """A new user's audit: rd_nav-auv3 published nothing in a run and fell out of the verdicts without a word."""
    from conftest import REPO

    from services.player.scenario import load_scenario
    from tools.report.paper import NO_DATA, paper_figures, silent_estimators

    demo = load_scenario(REPO / "scenarios" / "demo.yaml")
    published = {f"{e.kind}/{e.instance}": [truth(1.0)] for e in demo.estimators if e.instance != "auv3"}
    rows = silent_estimators(demo, published)
    assert [(r.kind, r.instance, r.verdict) for r in rows] == [("rd_nav", "auv3", NO_DATA)] * len(
        paper_figures()["rd_nav"]
    )
    assert "published nothing" in rows[0].note
    assert silent_estimators(demo, {**published, "rd_nav/auv3": [truth(1.0)]}) == []
    assert silent_estimators(None, {}) == []
