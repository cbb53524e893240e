"""What the report tells a reader beyond the figures (a new user's audit): a run cut short says so, and the LBL
"which hypothesis" verdict says why it has no data when the decision came at once."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from schemas import Header, ScenarioMarker, Truth
from shared.events import Event
from tools.report.data import cut_short
from tools.report.paper import _lbl_decision
from tools.report.reading import Recording

NS = 1_000_000_000


def marker(event: Literal["start", "end"], t_s: float) -> Event:
    msg = ScenarioMarker(
        header=Header(stamp_ns=int(t_s * NS), source="player/main"), event=event, scenario="demo", seed=1
    )
    return Event(msg.header.stamp_ns, "fixstream/scenario/demo", msg)


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
