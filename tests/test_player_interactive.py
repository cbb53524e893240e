"""The player's interactive-simulator support over a real Zenoh router (issue 5, ``docs/scenarios.md``).

A toy closed loop: each step the simulator publishes its state and a request, and the next state is the answer
(twice the request's value). With a service answering on Zenoh the published stream equals the offline one
(``scenario_events``: the simulator's in-process twin answers); with no answer (or answers naming another
player, or a wrong stamp) the player waits ``timeout_s``, reports ``exchange_timeout`` and the simulation goes on
without them, exactly as the same generator given an exchange that answers nothing. Open-loop scenarios are played
as before (``test_player_zenoh.py`` and ``test_e2e_record_replay.py`` run unchanged).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
import zenoh
from conftest import wait_until
from pydantic import Field

from schemas import Diagnostic, Header, Message, Truth
from schemas.rd_nav import CoordinatorReply
from services.player.player import PlayResult, play_scenario
from services.player.scenario import Scenario, parse_scenario
from services.player.simulators import Event, Exchange, ExchangeSpec, ScenarioContext, SimParams, register
from services.player.timeline import player_source, scenario_events, stamp
from shared import codec, keys
from shared.session import open_session
from shared.settings import ZenohSettings

pytestmark = pytest.mark.e2e

REQ = "fixstream/test/loop/request"
STATE = "fixstream/test/loop/state"
REPLY = "fixstream/test/loop/reply"


class LoopParams(SimParams):
    steps: int = Field(default=6, ge=1)
    step_s: float = Field(default=1.0, gt=0.0)
    timeout_s: float = Field(default=5.0, gt=0.0)


def _answers(msg: Message) -> tuple[str, str, int] | None:
    if isinstance(msg, CoordinatorReply):
        return msg.input_source, msg.input_key, msg.input_seq
    return None


def answer(key: str, request: Message, source: str | None = None, stamp_ns: int | None = None) -> CoordinatorReply:
    """The toy service: the answer's epoch is twice the request's value."""
    assert isinstance(request, Truth)
    return CoordinatorReply(
        header=Header(stamp_ns=request.header.stamp_ns if stamp_ns is None else stamp_ns),
        group="loop",
        input_key=key,
        input_source=request.header.source if source is None else source,
        input_seq=request.header.seq,
        epoch=2 * round(request.position_m[0]),
    )


@register("loop_test")
class LoopSim:
    """State x_k published, request x_k + 1, next state = the answer (or -1 without one)."""

    Params = LoopParams

    def __init__(self, params: LoopParams, rng: np.random.Generator, context: ScenarioContext) -> None:
        self.params = params
        self.context = context

    def exchange_spec(self) -> ExchangeSpec:
        return ExchangeSpec(REPLY, _answers, self.params.timeout_s)

    def events(self) -> Iterator[Event]:
        return self.interact(lambda reqs: [answer(e.key, e.msg) for e in reqs])

    def interact(self, exchange: Exchange) -> Iterator[Event]:
        value = 0
        for k in range(self.params.steps):
            t = round(k * self.params.step_s * 1e9)
            h = self.context.header(t)
            yield Event(t, STATE, Truth(header=h, platform="loop", position_m=[float(value), 0.0, 0.0]))
            req = Event(t, REQ, Truth(header=h, platform="loop", position_m=[float(value + 1), 0.0, 0.0]))
            yield req
            replies = exchange([req])
            value = replies[0].epoch if replies and isinstance(replies[0], CoordinatorReply) else -1


def loop_scenario(**params: Any) -> Scenario:
    return parse_scenario(
        {
            "name": "loop",
            "duration_s": 10.0,
            "wait_for": ["loopsvc/t1"],
            "simulators": [{"kind": "loop_test", "id": "loop", "params": params}],
        }
    )


class Responder:
    """A service on its own session: answers every request (``reply`` decides how), collects the diagnostics."""

    def __init__(self, endpoint: str, reply: Callable[[str, Message], CoordinatorReply | None] | None) -> None:
        self.session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
        self.reply = reply
        self.states: list[Message] = []
        self.diags: list[Diagnostic] = []
        self._lock = threading.Lock()
        self._pub = self.session.declare_publisher(REPLY)
        self._subs = [
            self.session.declare_subscriber(REQ, self._on_request),
            self.session.declare_subscriber(STATE, self._on_state),
            self.session.declare_subscriber(keys.diag("player", "t1"), self._on_diag),
        ]
        self._token = self.session.liveliness().declare_token(keys.alive("loopsvc", "t1"))  # after the subscribers

    def _on_request(self, sample: zenoh.Sample) -> None:
        msg = codec.decode(sample.payload.to_bytes(), str(sample.encoding))
        out = self.reply(str(sample.key_expr), msg) if self.reply is not None else None
        if out is not None:
            self._pub.put(codec.encode(out), encoding=codec.zenoh_encoding(codec.encoding_of(CoordinatorReply)))

    def _on_state(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.states.append(codec.decode(sample.payload.to_bytes(), str(sample.encoding)))

    def _on_diag(self, sample: zenoh.Sample) -> None:
        msg = codec.decode(sample.payload.to_bytes(), str(sample.encoding))
        assert isinstance(msg, Diagnostic)
        with self._lock:
            self.diags.append(msg)

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self._pub.undeclare()
        self._token.undeclare()
        self.session.close()


def play(endpoint: str, scenario: Scenario) -> PlayResult:
    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    try:
        return play_scenario(session, scenario, instance="t1", rate=0.0)  # waits for the responder's token
    finally:
        session.close()


def states(events: list[Event]) -> list[Message]:
    return [e.msg for e in events if e.key == STATE]


def test_answers_over_zenoh_give_the_offline_stream(router: str) -> None:
    sc = loop_scenario()
    svc = Responder(router, lambda key, msg: answer(key, msg))
    try:
        result = play(router, sc)
        offline = [
            Event(
                e.stamp_ns,
                e.key,
                e.msg.model_copy(update={"header": e.msg.header.model_copy(update={"source": "player/t1"})}),
            )
            for e in scenario_events(sc)
        ]
        assert wait_until(lambda: len(svc.states) == 6, timeout=10)
    finally:
        svc.close()
    assert result.completed and result.exchanges == {"loop": {"requests": 6, "answers": 6}}
    assert svc.states == states(offline)
    assert [m.position_m[0] for m in svc.states] == [0.0, 2.0, 6.0, 14.0, 30.0, 62.0]  # type: ignore[attr-defined]
    assert result.published == {STATE: 6, REQ: 6} and not svc.diags


@pytest.mark.parametrize(
    "reply",
    [
        None,  # nobody answers
        lambda key, msg: answer(key, msg, source="player/other"),  # answers to another player
        lambda key, msg: answer(key, msg, stamp_ns=msg.header.stamp_ns + 1),  # not this request's stamp
    ],
    ids=["silent", "other_player", "wrong_stamp"],
)
def test_missing_answers_time_out_are_reported_and_the_run_goes_on(
    router: str, reply: Callable[[str, Message], CoordinatorReply] | None
) -> None:
    sc = loop_scenario(steps=3, timeout_s=0.3)
    svc = Responder(router, reply)
    try:
        result = play(router, sc)
        assert wait_until(lambda: len(svc.states) == 3 and len(svc.diags) == 3, timeout=10)
    finally:
        svc.close()
    sim = LoopSim(LoopParams(steps=3, timeout_s=0.3), np.random.default_rng(0), _context(sc))
    unanswered = list(stamp(sim.interact(lambda reqs: []), player_source("t1")))
    assert result.completed
    assert result.exchanges == {"loop": {"requests": 3, "answers": 0, "timeouts": 3, "missing": 3}}
    assert svc.states == states(unanswered)
    assert [m.position_m[0] for m in svc.states] == [0.0, -1.0, -1.0]  # type: ignore[attr-defined]
    assert {d.reason for d in svc.diags} == {"exchange_timeout"} and [d.count for d in svc.diags] == [1, 2, 3]
    assert all(d.key == REPLY and d.service == "player" and d.instance == "t1" for d in svc.diags)


def _context(sc: Scenario) -> ScenarioContext:
    return ScenarioContext(scenario=sc.name, frame_id=sc.frame_id, duration_ns=sc.duration_ns, seed=sc.seed)
