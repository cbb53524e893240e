"""The player's side of a closed loop: wait on Zenoh for a service's answers to an interactive simulator's requests.

An interactive simulator (:class:`~services.player.simulators.InteractiveSimulator`) yields a chunk of events,
some of which are requests (for the ``rd_group`` simulator: what the AUVs send to the base coordinator). Once the
player has published the chunk, the simulator calls the exchange with those requests; :class:`ZenohExchange`
waits until the service's reply to each has arrived on the simulator's reply key, and returns them in request
order. A reply names its request by (``header.source``, key, ``header.seq``) (the player stamps the requests,
counting ``seq`` per key from 0) and carries the request's stamp in its own ``header.stamp_ns``.

If the answers do not all arrive within the simulator's ``timeout_s`` of wall time, the exchange returns those
that did, logs a warning and reports ``exchange_timeout`` on ``fixstream/diag/player/<instance>``: the simulation
goes on without the missing decisions (for ``rd_group``: the previous beacon assignment stays in force), and a
reply arriving later is ignored. The counts are in :attr:`ZenohExchange.stats` (and the player's result).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import Counter

import zenoh

from schemas import Diagnostic, Header, Message
from shared import codec, keys
from shared.recovery import Recovery
from shared.settings import ZenohSettings

from .simulators import Event, ExchangeSpec

log = logging.getLogger("fixstream.player")


class ZenohExchange:
    """Answers to one interactive simulator's requests, received on its reply key (see the module docstring)."""

    def __init__(
        self,
        session: zenoh.Session,
        sim_id: str,
        spec: ExchangeSpec,
        source: str,
        instance: str = "default",
        stop: threading.Event | None = None,
        recovery: Recovery | None = None,
    ) -> None:
        self.session = session
        self.sim_id = sim_id
        self.spec = spec
        self.source = source
        self.instance = instance
        self.stop = stop or threading.Event()
        self.stats: Counter[str] = Counter()
        self._cond = threading.Condition()
        self._replies: dict[tuple[str, int], Message] = {}
        self._seq: Counter[str] = Counter()
        # the replies are control messages: recovered after a router outage where ``recovery`` covers their key
        recovery = recovery or Recovery.of(ZenohSettings())
        self._sub = recovery.declare_subscriber(session, spec.reply_key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            msg = codec.decode(sample.payload.to_bytes(), str(sample.encoding))
        except codec.DecodeError:
            self.stats["undecodable"] += 1
            return
        ident = self.spec.answers(msg)
        if ident is None or ident[0] != self.source:
            return  # not a reply, or a reply to another player
        with self._cond:
            self._replies[(ident[1], ident[2])] = msg
            self._cond.notify_all()

    def __call__(self, requests: list[Event]) -> list[Message]:
        wanted: list[tuple[tuple[str, int], int]] = []
        for ev in requests:
            wanted.append(((ev.key, self._seq[ev.key]), ev.stamp_ns))
            self._seq[ev.key] += 1
        self.stats["requests"] += len(wanted)
        deadline = time.monotonic() + self.spec.timeout_s
        with self._cond:
            while not self.stop.is_set():
                if all(self._answered(w, stamp) for w, stamp in wanted):
                    break
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(min(remaining, 0.1))
            got = [self._replies.pop(w) for w, stamp in wanted if self._answered(w, stamp)]
            for w, _ in wanted:  # a late reply to a request given up on must not answer a later one
                self._replies.pop(w, None)
        self.stats["answers"] += len(got)
        missing = len(wanted) - len(got)
        if missing and not self.stop.is_set():
            self.stats["timeouts"] += 1
            self.stats["missing"] += missing
            self._report(missing, len(wanted), wanted[-1][1] if wanted else 0)
        return got

    def _answered(self, want: tuple[str, int], stamp_ns: int) -> bool:
        reply = self._replies.get(want)
        return reply is not None and reply.header.stamp_ns == stamp_ns

    def _report(self, missing: int, asked: int, stamp_ns: int) -> None:
        detail = (
            f"{missing} of {asked} answers on {self.spec.reply_key} missing after {self.spec.timeout_s:g} s "
            f"(simulator {self.sim_id}, stamp {stamp_ns} ns); the run goes on without them"
        )
        log.warning("exchange_timeout: %s", detail)
        diag = Diagnostic(
            header=Header(stamp_ns=stamp_ns, source=f"player/{self.instance}"),
            service="player",
            instance=self.instance,
            level="warning",
            key=self.spec.reply_key,
            reason="exchange_timeout",
            detail=detail,
            count=self.stats["timeouts"],
            counts={"exchange_timeout": self.stats["timeouts"]},
        )
        with contextlib.suppress(Exception):  # reporting must not end the run
            self.session.put(
                keys.diag("player", self.instance),
                codec.encode(diag),
                encoding=codec.zenoh_encoding(codec.encoding_of(Diagnostic)),
            )

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._sub.undeclare()


__all__ = ["ZenohExchange"]
