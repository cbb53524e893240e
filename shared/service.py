"""The service base every fixstream process builds on.

A :class:`Service` subscribes to key expressions, decodes and validates each sample, dispatches it to a
handler (which calls a pure core), and publishes what the handler returns. Around that it

* reports every rejected payload on ``fixstream/diag/<service>/<instance>`` (key, reason, running counts),
* declares a liveliness token ``fixstream/alive/<service>/<instance>``,
* answers the queryable ``fixstream/status/<service>/<instance>`` (counters, last error, config),
* stamps ``header.source`` and a per-key ``header.seq`` on everything it publishes,
* ends a scenario run once every message the player announced has arrived (below),
* shuts down cleanly on SIGTERM/SIGINT.

Samples are queued by a delivery thread per subscription and processed by one thread in arrival order, so a
service is deterministic for a given input order (architecture rule 1). Zenoh hands each subscription's samples to
its delivery thread through a FIFO of ``FIFO_SAMPLES``; the thread takes every sample that has arrived in one go
(``try_recv``, holding the GIL: one hand-over of the GIL per burst, where a Python callback costs one per sample)
and puts them in the queue. The queue is bounded in items and bytes; when it is full, the delivery thread is held
(which fills the FIFO, then holds Zenoh's thread and slows blocking publishers) for at most ``enqueue_block_s``, then
samples are dropped and counted (``queue_full``) until the queue has drained to half, so a busy service never holds
Zenoh's thread long enough to lose its session. A payload larger than ``max_payload_bytes`` is refused unread.

**Faults are counted where they happen.** Every sample's ``(header.source, header.seq)`` per key goes through a
:class:`~shared.seq.SeqTracker`: transport gaps are ``lost`` (with a ``seq_gap`` diagnostic), repeats and restarts
are counted apart. Every rejection has a reason, every output that cannot be published is reported
(``publish_failed``) and the service goes on.

**End of a scenario.** Zenoh keeps one publisher's order per subscription, but each subscription is
delivered on its own thread, so the player's end marker (on ``fixstream/scenario/<name>``) can overtake
the last data. The marker carries the number of messages the player published per key; the base counts
what arrives on every key the service subscribes to and calls :meth:`Service.on_scenario_end` only once
every announced message on those keys has arrived — after the sample that completes the count, whatever
that sample's fate (accepted or rejected). Only the marker's own publisher counts: a message counts towards an
end marker from ``player/<x>`` if it came from ``player/<x>`` (its ``header.source``) and is not a repeat of
the last seq on its key; an end marker from any other source is refused (``foreign_marker``), and a payload
that does not even unpack counts for nobody, so junk on the bus can neither end a run early nor leak it into the
next. If some never arrive, the run ends anyway ``end_wait_s`` of
wall time after the last counted sample, at the next start marker, or at shutdown (logged and counted as
``incomplete`` in the status); :meth:`Service.run_offline` ends it after its last event. Services therefore
implement ``on_scenario_end`` as a plain flush.
"""

from __future__ import annotations

import contextlib
import gc
import json
import logging
import queue
import signal
import threading
import time
import traceback
from collections import Counter, OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from types import FrameType
from typing import Any, ClassVar, Literal, NamedTuple

import zenoh

from schemas import Diagnostic, Header, Message, ScenarioMarker
from schemas.base import MAX_INPUT_STAMP_NS

from . import codec, keys
from .errors import InputRejected
from .inbox import Inbox
from .recovery import Publisher, Recovery
from .seq import IN_ORDER, SeqTracker
from .session import open_session, refuse_namesake
from .settings import ServiceSettings, ZenohSettings

log = logging.getLogger("fixstream.service")


class Output(NamedTuple):
    """A message to publish on a key (a named tuple: every handler builds one per output, and a tuple is built in
    half the time of a frozen dataclass)."""

    key: str
    msg: Message


Handler = Callable[[str, Message], Iterable[Output] | None]
RawHandler = Callable[[str, bytes, str], Iterable[Output] | None]
#: the message types a handler takes on a key, or None: the key is not the handler's (the sample is counted as
#: ``ignored`` and never validated)
KeyTypes = Callable[[str], tuple[type[Message], ...] | None]
#: repairs an unpacked payload that failed validation against ``model`` (a scan that loses its bad plots rather than
#: itself), or re-raises the :class:`~shared.codec.DecodeError`
Salvage = Callable[[type[Message], Any, codec.DecodeError], Message]


@dataclass
class Subscription:
    """What a service listens to, and how its samples reach the handler.

    The typed path (``handler``): the base unpacks each payload once (its header feeds the seq checks and the end of
    a run), validates it once into the model its encoding names (``salvage`` may repair what fails), refuses a type
    the handler does not take (``accepts``: the types, or a :data:`KeyTypes` per key; ``others="ignore"`` counts
    other types as ``ignored`` instead), refuses a stamp older than the last on its key if ``monotonic``, and calls
    ``handler(key, msg)``. Empty ``accepts``: any message. Every refusal is counted and reported with its reason.

    ``raw_handler(key, payload, encoding)`` takes the bytes as they arrived instead (the recorder, which keeps what
    fails validation)."""

    key_expr: str
    handler: Handler | None = None
    accepts: tuple[type[Message], ...] | KeyTypes = ()
    others: Literal["reject", "ignore"] = "reject"
    monotonic: bool = False
    salvage: Salvage | None = None
    raw_handler: RawHandler | None = None


@dataclass
class Counters:
    received: int = 0
    #: taken by the service (``ignored`` included): ``received == accepted + rejected``
    accepted: int = 0
    rejected: int = 0
    #: accepted samples no handler had a use for (a key or type the service does not read)
    ignored: int = 0
    published: int = 0
    #: samples dropped before processing (the inbound queue was full), never in ``received``
    dropped: int = 0
    #: outputs a handler produced that could not be published
    publish_failed: int = 0
    rejected_by_reason: Counter[str] = field(default_factory=Counter)
    last_error: str | None = None
    last_error_key: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return {
            "received": self.received,
            "accepted": self.accepted,
            "rejected": self.rejected,
            "ignored": self.ignored,
            "published": self.published,
            "dropped": self.dropped,
            "publish_failed": self.publish_failed,
            "rejected_by_reason": dict(self.rejected_by_reason),
            "last_error": self.last_error,
            "last_error_key": self.last_error_key,
        }


@dataclass
class _PendingEnd:
    """An end marker waiting for the messages its publisher announced on the service's keys."""

    marker: ScenarioMarker
    #: (key, the marker's source) -> messages announced
    expected: dict[tuple[str, str], int]


#: the publishers whose end markers end runs, and whose messages count towards them
PLAYER_PREFIX = "player/"
#: the source run_offline gives the events no publisher stamped
OFFLINE_PLAYER = PLAYER_PREFIX + "offline"
#: (key, source) pairs whose arrivals are counted for end markers, at most
MAX_COUNTED_PAIRS = 65_536


class _DiagLimiter:
    """Token bucket per reason so a flood of bad input cannot flood the diag key (counts are kept)."""

    def __init__(self, rate_hz: float, burst: int) -> None:
        self.rate_hz = rate_hz
        self.burst = float(burst)
        self._tokens: dict[str, float] = {}
        self._last: dict[str, float] = {}

    def allow(self, reason: str, now: float) -> bool:
        tokens = self._tokens.get(reason, self.burst)
        tokens = min(self.burst, tokens + (now - self._last.get(reason, now)) * self.rate_hz)
        self._last[reason] = now
        allowed = tokens >= 1.0
        self._tokens[reason] = tokens - 1.0 if allowed else tokens
        return allowed


_STOP = object()
#: samples processed between two looks at the clock while the inbox is not empty
_BURST = 64
#: samples Zenoh holds per subscription for its delivery thread (the capacity of the channel Zenoh itself puts
#: between its network thread and a Python callback)
FIFO_SAMPLES = 256


class Service:
    """Base class of every fixstream process that subscribes and publishes."""

    name: ClassVar[str] = "service"
    #: diagnostics per reason per second once the burst is spent (0: no limit)
    diag_rate_hz: ClassVar[float] = 50.0
    diag_burst: ClassVar[int] = 2000
    #: declared publishers kept (least recently used beyond this are undeclared; a key's seq is kept regardless)
    max_publishers: ClassVar[int] = 4096
    #: keys received on that are declared to the session (:meth:`_declare_wire_key`), at most
    max_wire_keys: ClassVar[int] = 4096
    #: how long before its start marker a player's first input may be taken and still count as the run's own, s
    #: (the marker is published first; only the two subscriptions' delivery threads can put its data ahead of it)
    stray_window_s: ClassVar[float] = 0.5
    #: how long a process waits for a namesake's liveliness token to go before it refuses to start, s
    namesake_wait_s: ClassVar[float] = 12.0

    def __init__(self, settings: ServiceSettings, zenoh_settings: ZenohSettings | None = None) -> None:
        self.settings = settings
        self.zenoh_settings = zenoh_settings or ZenohSettings()
        #: which of its keys are published and subscribed with recovery (shared/recovery.py)
        self.recovery = Recovery.of(self.zenoh_settings)
        self.instance = keys.chunk(settings.instance)
        self.source = f"{self.name}/{self.instance}"
        Header(stamp_ns=0, source=self.source)  # publish stamps it unvalidated online: check it once here
        self.counters = Counters()
        self.session: zenoh.Session | None = None
        self._queue = Inbox(settings.queue_size, settings.queue_max_bytes, settings.enqueue_block_s)
        self._max_payload = settings.max_payload_bytes
        self.seq = SeqTracker()
        self._stop = threading.Event()
        #: what releases a delivery thread that a full inbox holds (it then drops and counts): the stop itself for
        #: a service; the recorder releases its senders only after recording what was still in flight at its stop
        self._release_senders = self._stop
        self._seq: dict[str, int] = {}
        self._publishers: OrderedDict[str, Publisher] = OrderedDict()
        #: the message type whose encoding each publisher was declared with
        self._publisher_model: dict[str, type[Message]] = {}
        #: keys received on, declared to the session (None: the declaration failed; not retried)
        self._wire_keys: dict[str, zenoh.KeyExpr | None] = {}
        self._last_stamp: dict[str, int] = {}
        #: the data clock: stamp of the last message a handler took (a start marker sets it back); what a diagnostic
        #: about a payload without a usable stamp, or about no payload, is stamped with
        self.data_clock_ns = 0
        self._limiter = _DiagLimiter(self.diag_rate_hz, self.diag_burst)
        self.diag_suppressed = 0
        self._declared: list[Any] = []
        #: the delivery thread of each subscriber (by ``id``; :meth:`_subscribe`)
        self._delivery: dict[int, threading.Thread] = {}
        self._subs: list[Subscription] = []
        #: per key seen: its subscription (the first that matches, or None) and whether it is a scenario marker key
        self._routes: dict[str, tuple[Subscription | None, bool]] = {}
        #: what an offline run (no session) published, in order
        self.outbox: list[Output] = []
        self.started_at = time.time()
        self.rx_time_ns = 0
        #: a player's samples arrived per (subscribed data key, source), not yet consumed by an end of scenario
        self._arrived: Counter[tuple[str, str]] = Counter()
        self._last_arrival = time.monotonic()
        self._pending_end: _PendingEnd | None = None
        #: ends of scenario runs: "complete" (every announced message arrived) or "incomplete"
        self.scenario_ends: Counter[str] = Counter()
        #: fresh cores started so far, this one included (:meth:`new_run`)
        self.sessions = 1
        #: inputs the core has taken since it was started (:meth:`new_run` sets it back to 0), and when the first
        #: of each source arrived (its receive time, ns: not when it was processed, which a slow core delays)
        self._taken_since_new_run = 0
        self._first_taken: dict[str, int] = {}
        #: start markers that found the core fed since the last run ended, and started a fresh one
        self.stray_resets = 0

    # ----- to override ------------------------------------------------------------------------
    def subscriptions(self) -> list[Subscription]:
        """The key expressions this service listens to."""
        return []

    def on_scenario_start(self, marker: ScenarioMarker) -> Iterable[Output]:
        """Called when the player's start marker arrives (after ending a previous run still pending)."""
        return ()

    def on_scenario_end(self, marker: ScenarioMarker) -> Iterable[Output]:
        """Called once every message the player's end marker announced on this service's keys has arrived
        (or could not be waited for any longer): the run's last outputs (:meth:`flush_run`), then, with
        ``reset_on_scenario_end`` (the default), a fresh core (:meth:`new_run`) for the next run."""
        out = list(self.flush_run(marker))
        if self.settings.reset_on_scenario_end:
            out.extend(self.new_run(f"scenario {marker.scenario} ended"))
        return out

    def flush_run(self, marker: ScenarioMarker) -> Iterable[Output]:
        """The outputs of what the core still holds at the end of a run (buffers, open epochs)."""
        return ()

    def new_run(self, reason: str) -> Iterable[Output]:
        """Start a fresh core. Services replace their core, then call this (it counts :attr:`sessions` and logs);
        the outputs announce the new session where a service has such a message."""
        self.sessions += 1
        self._taken_since_new_run = 0
        self._first_taken.clear()
        self._last_stamp.clear()
        log.info("%s: %s; fresh core (session %d)", self.source, reason, self.sessions)
        return ()

    def on_idle(self) -> Iterable[Output]:
        """Housekeeping on the wall clock (never estimation): called at least every 0.2 s."""
        return ()

    def on_stop(self) -> None:
        """Release resources (files, ...) before the session closes."""

    def status_extra(self) -> dict[str, Any]:
        """Service-specific figures for the status queryable."""
        return {}

    # ----- public API --------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        return {
            "service": self.name,
            "instance": self.instance,
            "uptime_s": round(time.time() - self.started_at, 3),
            "queue_depth": self._queue.qsize(),
            "queue_bytes": self._queue.bytes,
            "counters": self.counters.as_dict(),
            # the key expressions it listens to, every service alike (its scenario markers aside)
            "subscribed": [sub.key_expr for sub in self._subs],
            "seq": self.seq.as_dict(),
            "diag_suppressed": self.diag_suppressed,
            "scenario": {
                "end_pending": self._pending_end is not None,
                "ends": dict(self.scenario_ends),
                "stray_resets": self.stray_resets,
            },
            "config": self.settings.model_dump(mode="json"),
            **self.status_extra(),
        }

    def stop(self) -> None:
        self._stop.set()
        self._queue.put_control(_STOP)

    def install_signal_handlers(self) -> None:
        def handler(signum: int, frame: FrameType | None) -> None:
            log.info("%s: signal %d, stopping", self.source, signum)
            self.stop()

        signal.signal(signal.SIGTERM, handler)
        signal.signal(signal.SIGINT, handler)

    def _open_alone(self) -> bool:
        """Open the session, the only process of this name and instance on the network (:func:`refuse_namesake`:
        :class:`StartupError` otherwise), before anything is declared or stopped, so a refused namesake touches
        nothing of the one that runs. False (the session closed again) when stopped during the wait."""
        self.session = session = open_session(self.zenoh_settings)
        alone = False
        try:
            refuse_namesake(session, keys.alive(self.name, self.instance), self.namesake_wait_s, self._stop)
            alone = not self._stop.is_set()
        finally:
            if not alone:  # refused, stopped, or interrupted: nothing was declared
                with contextlib.suppress(Exception):
                    session.close()
        return alone

    def run(self) -> int:
        """Open the session, serve until stopped, close cleanly. Returns a process exit code. Another process alive
        under the same name and instance: :class:`StartupError` (:func:`refuse_namesake`)."""
        if not self._open_alone():
            return 0
        try:
            self._declare()
            # what exists now (modules, schemas, the core) lives as long as the process: out of the collector's
            # way, so that its full passes cost what the messages in flight cost, not the whole interpreter
            gc.freeze()
            self._loop()
        finally:
            self._shutdown()
        return 0

    def publish(self, key: str, msg: Message) -> None:
        """Stamp source and per-key seq, encode and put (offline: append to :attr:`outbox`).

        Online the stamped bytes are encoded straight from ``msg`` (:func:`codec.encode_stamped`: the same bytes as
        encoding the stamped copy, which is only built offline)."""
        seq = self._seq.get(key, 0)
        self._seq[key] = seq + 1
        if self.session is None:
            h = msg.header
            header = Header(stamp_ns=h.stamp_ns, frame_id=h.frame_id, source=self.source, seq=seq)
            self.outbox.append(Output(key, msg.model_copy(update={"header": header})))
            self.counters.published += 1
            return
        if msg.header.stamp_ns < 0:  # what Header(...) above refuses (a core building its outputs unvalidated)
            raise ValueError(f"{type(msg).__name__} on {key}: negative stamp {msg.header.stamp_ns} ns")
        model = type(msg)
        pub = self._publishers.get(key)
        if pub is None:
            pub = self._declare_publisher(key, model)
        else:
            self._publishers.move_to_end(key)
        if self._publisher_model[key] is model:  # the publisher's own encoding: 1 µs cheaper than naming it
            pub.put(codec.encode_stamped(msg, self.source, seq))
        else:
            pub.put(codec.encode_stamped(msg, self.source, seq), encoding=codec.zenoh_encoding_of(model))
        self.counters.published += 1

    def _declare_publisher(self, key: str, model: type[Message]) -> Publisher:
        """A publisher on ``key`` whose encoding is ``model``'s (the type first published there), undeclaring the
        least recently used one beyond :attr:`max_publishers`."""
        assert self.session is not None
        if len(self._publishers) >= self.max_publishers:
            old_key, old = self._publishers.popitem(last=False)
            del self._publisher_model[old_key]
            with contextlib.suppress(Exception):
                old.undeclare()
        pub = self.recovery.declare_publisher(
            self.session, key, congestion_control=zenoh.CongestionControl.BLOCK, encoding=codec.zenoh_encoding_of(model)
        )
        self._publishers[key] = pub
        self._publisher_model[key] = model
        return pub

    def reject(self, key: str, reason: str, detail: str = "", stamp_ns: int | None = None) -> None:
        """Count a rejected input and report it on the diag key (rate-limited per reason), stamped ``stamp_ns``
        (None: the data clock)."""
        c = self.counters
        c.rejected += 1
        c.rejected_by_reason[reason] += 1
        c.last_error = f"{reason}: {detail}" if detail else reason
        c.last_error_key = key
        log.debug("%s rejected %s on %s: %s", self.source, reason, key, detail)
        self.report(
            key,
            reason,
            detail,
            count=c.rejected_by_reason[reason],
            counts=dict(c.rejected_by_reason),
            stamp_ns=stamp_ns,
        )

    def count_event(
        self,
        events: Counter[str],
        key: str,
        reason: str,
        detail: str = "",
        *,
        n: int = 1,
        level: Literal["info", "warning", "error"] = "warning",
        stamp_ns: int | None = None,
        report: bool = True,
    ) -> None:
        """Count an event the service noticed in an input it took (not a refusal) in ``events``, and report it on the
        diag key with the running counts (unless ``report`` is False: counted only)."""
        events[reason] += n
        if report:
            self.report(key, reason, detail, count=events[reason], counts=dict(events), level=level, stamp_ns=stamp_ns)

    def report(
        self,
        key: str,
        reason: str,
        detail: str = "",
        *,
        count: int,
        counts: dict[str, int],
        level: Literal["info", "warning", "error"] = "warning",
        stamp_ns: int | None = None,
    ) -> None:
        """Publish a Diagnostic stamped ``stamp_ns`` (None: the data clock), rate-limited per reason online; counts
        are never lost, only messages."""
        if self.session is not None and self.diag_rate_hz > 0 and not self._limiter.allow(reason, time.monotonic()):
            self.diag_suppressed += 1
            return
        if stamp_ns is None:
            stamp_ns = self.data_clock_ns
        try:
            self._publish_diag(key, reason, detail, count, counts, level, stamp_ns)
        except Exception:  # a diagnostic that cannot go out is logged; the counts it carried are kept
            self.diag_suppressed += 1
            log.error("%s: diagnostic %s on %s not published:\n%s", self.source, reason, key, traceback.format_exc())

    def _publish_diag(
        self,
        key: str,
        reason: str,
        detail: str,
        count: int,
        counts: dict[str, int],
        level: Literal["info", "warning", "error"],
        stamp_ns: int,
    ) -> None:
        diag = Diagnostic(
            header=Header(stamp_ns=stamp_ns),
            service=self.name,
            instance=self.instance,
            level=level,
            key=key,
            reason=reason,
            detail=detail[:4000],
            count=count,
            counts=counts,
        )
        self.publish(keys.diag(self.name, self.instance), diag)

    def run_offline(self, events: Iterable[tuple[str, Message]]) -> list[Output]:
        """Feed messages through the same decode/validate/dispatch path without Zenoh; return outputs.

        Each message is encoded with the wire codec first, so an offline run and a run over Zenoh see
        identical bytes. Outputs (fixes and diagnostics) are stamped with source and seq as online. Messages
        that no publisher stamped (``header.source`` empty: hand-built events) are stamped as a player stamps
        them, ``player/offline`` with a per-key seq from 0 (from 0 again after a start marker); messages that
        carry a source (the player's events, a recording) keep their header.
        """
        if self.session is not None:
            raise RuntimeError("run_offline is for a service without a Zenoh session")
        self._subs = self.subscriptions()
        start = len(self.outbox)
        seq: Counter[str] = Counter()
        for key, msg in events:
            if msg.header.source:
                payload = codec.encode(msg)
            else:
                if isinstance(msg, ScenarioMarker) and msg.event == "start":
                    seq.clear()
                payload = codec.encode_stamped(msg, OFFLINE_PLAYER, seq[key])
                seq[key] += 1
            self.process(key, payload, codec.encoding_of(type(msg)), rx_time_ns=0)
        self._end_scenario(force=True)  # nothing more will arrive
        return self.outbox[start:]

    def process(self, key: str, payload: bytes, encoding: str, rx_time_ns: int | None = None) -> None:
        """Decode, validate and dispatch one sample (also callable without Zenoh, for tests).

        ``rx_time_ns`` is the wall time the sample arrived (for logs and recordings, never estimation);
        handlers read it as ``self.rx_time_ns``.
        """
        self.rx_time_ns = rx_time_ns if rx_time_ns is not None else time.time_ns()
        counters = self.counters
        counters.received += 1
        if len(payload) > self._max_payload:
            self.reject(key, "payload_too_large", f"{len(payload)} bytes > max_payload_bytes {self._max_payload}")
            return
        sub, scenario = self._routes.get(key) or self._route(key)
        try:  # once: the header for the accounting, the object for the validation
            obj, unpack_error = codec.unpack(payload), None
        except codec.DecodeError as exc:
            obj, unpack_error = None, exc
        counted = False
        if sub is not None:
            try:
                counted = self._account(key, scenario, None if unpack_error else codec.header_of(obj))
            except InputRejected as exc:
                self.reject(key, exc.reason, exc.detail)
                return
        outputs = self._dispatch(key, payload, encoding, sub, scenario, obj, unpack_error)
        if outputs is not None:
            counters.accepted += 1
            if outputs:  # most samples of most services: nothing to publish (already truth-tested: `or ()`)
                self._publish_all(outputs)
        if counted and self._pending_end is not None:
            self._end_scenario(force=False)

    def _account(self, key: str, scenario: bool, header: tuple[str, int, int] | None) -> bool:
        """The input stamp bound, seq checks of the sample's publisher (``header``: its source, seq and stamp);
        True if the sample counts towards its player's end marker (``scenario``: ``key`` is a marker key). Raises
        InputRejected for a stamp beyond the input bound."""
        if header is None:
            return False  # does not unpack: the decode reports it; it counts for nobody
        source, seq, stamp = header
        if stamp > MAX_INPUT_STAMP_NS:
            # valid as a message, but no core may take it: outputs derived from it could not be stamped
            raise InputRejected("stamp_out_of_range", f"stamp {stamp} ns > {MAX_INPUT_STAMP_NS} ns (the input bound)")
        if scenario:
            return False  # markers: a missing one shows as a run that ends by end_wait_s
        check = self.seq.check(key, source, seq)
        if check is IN_ORDER:
            pass
        elif check.event == "seq_gap":
            self.report(
                key,
                "seq_gap",
                f"{check.missing} lost on {key} from {source}: expected seq {check.expected}, got {seq}",
                count=self.seq.events["seq_gap"],
                counts=self.seq.as_dict(),
                level="warning",
                stamp_ns=self._diag_stamp(stamp),  # the header is not validated yet: a negative stamp is possible
            )
        elif check.event == "duplicate":
            return False
        if not source.startswith(PLAYER_PREFIX):
            return False
        pair = (key, source)
        if pair not in self._arrived and len(self._arrived) >= MAX_COUNTED_PAIRS:
            return False
        self._arrived[pair] += 1
        self._last_arrival = time.monotonic()
        return True

    def _dispatch(
        self,
        key: str,
        payload: bytes,
        encoding: str,
        sub: Subscription | None,
        scenario: bool,
        obj: Any,
        unpack_error: codec.DecodeError | None,
    ) -> Iterable[Output] | None:
        """The handler's outputs (``()`` if none), or None when the sample was rejected (and reported).

        ``obj`` is the unpacked payload (``unpack_error`` if it did not unpack): validated here, once."""
        try:
            if sub is not None and sub.raw_handler is not None:
                return sub.raw_handler(key, payload, encoding) or ()
            accepts = () if sub is None else sub.accepts
            types = accepts(key) if callable(accepts) else accepts
            if types is None:
                self.counters.ignored += 1
                return ()
            model = codec.model_for_encoding(encoding)  # the encoding is judged first, as codec.decode does
            if unpack_error is not None:
                raise unpack_error
            try:
                msg = codec.validate(model, obj)
            except codec.DecodeError as exc:
                if sub is None or sub.salvage is None:
                    raise
                msg = sub.salvage(model, obj, exc)
            if scenario and isinstance(msg, ScenarioMarker):
                return self._on_marker(msg)
            if sub is None or sub.handler is None:
                raise InputRejected("no_handler", f"nothing handles {key}")
            if types and not isinstance(msg, types):
                if sub.others == "ignore":
                    self.counters.ignored += 1
                    return ()
                allowed = ", ".join(m.__name__ for m in types)
                raise InputRejected("unexpected_type", f"{type(msg).__name__} on {key}; expects {allowed}")
            if sub.monotonic:
                self._check_monotonic(key, msg)
            self._taken_since_new_run += 1  # a core that refuses it may have looked at it: counted all the same
            if msg.header.source not in self._first_taken:
                self._first_taken[msg.header.source] = self.rx_time_ns
            outputs = sub.handler(key, msg) or ()
            if msg.header.stamp_ns > self.data_clock_ns:
                self.data_clock_ns = msg.header.stamp_ns
            return outputs
        except codec.DecodeError as exc:
            self.reject(key, exc.reason, exc.detail, self._stamp_of(obj))
        except InputRejected as exc:
            self.reject(key, exc.reason, exc.detail, self._stamp_of(obj))
        except Exception as exc:  # a bug must not kill the service; it is reported like bad input
            log.error("%s: handler failed on %s:\n%s", self.source, key, traceback.format_exc())
            self.reject(key, "internal_error", f"{type(exc).__name__}: {exc}", self._stamp_of(obj))
        return None

    def _stamp_of(self, obj: Any) -> int:
        """What a diagnostic about the unpacked payload ``obj`` is stamped with: its header's stamp when the header
        unpacks and the stamp is within the input bound, else the data clock."""
        header = codec.header_of(obj)
        return self.data_clock_ns if header is None else self._diag_stamp(header[2])

    def _diag_stamp(self, stamp_ns: int) -> int:
        """An input's stamp, for a diagnostic about it, when it is within the input bound, else the data clock."""
        return stamp_ns if 0 <= stamp_ns <= MAX_INPUT_STAMP_NS else self.data_clock_ns

    def _on_marker(self, marker: ScenarioMarker) -> list[Output]:
        """A start marker ends a run still pending; an end marker waits for what it announced (module doc)."""
        source = marker.header.source
        if not source.startswith(PLAYER_PREFIX):
            raise InputRejected("foreign_marker", f"{marker.event} marker from {source!r}, not a player")
        if marker.event == "start":
            self.data_clock_ns = marker.header.stamp_ns  # a new run: its stamps start again
            out = self._end_scenario(force=True, publish=False) if self._pending_end is not None else []
            out.extend(self._drop_stray_inputs(marker))
            self.seq.forget_source(source)  # the player counts its seq from 0 again
            return out + list(self.on_scenario_start(marker) or ())
        if self._pending_end is not None:  # two end markers in a row: the first run is over
            self._end_scenario(force=True)
        expected = {
            (k, source): n
            for k, n in marker.published.items()
            if n > 0 and not _is_scenario_key(k) and self._match(k) is not None
        }
        self._pending_end = _PendingEnd(marker, expected)
        return self._end_scenario(force=False, publish=False)

    def _drop_stray_inputs(self, marker: ScenarioMarker) -> list[Output]:
        """A run starts from a fresh core. If the core has taken inputs since the last run ended (a message that
        came between two runs, from a late publisher, a replay of some keys or anyone else), their state would bend
        the new run (a stamp 30 s in made every earlier stamp of the next run ``stamp_backwards``), so a fresh core
        is started and the drop is reported (``stray_inputs``).

        The run's own first samples may be taken just before its marker (the marker has a subscription of its own,
        and Zenoh keeps no order across subscriptions): inputs from the marker's source that arrived less than
        :attr:`stray_window_s` before it (receive times, so a slow core does not stretch the window) are taken to
        be those and kept. Not with ``reset_on_scenario_end`` off, where runs are meant to carry state over."""
        taken = self._taken_since_new_run
        if not taken or not self.settings.reset_on_scenario_end:
            return []
        own = self._first_taken.get(marker.header.source)
        foreign = len(self._first_taken) > (own is not None)
        if not foreign and own is not None and (self.rx_time_ns - own) * 1e-9 < self.stray_window_s:
            return []
        self.stray_resets += 1
        detail = f"{taken} input(s) taken since the last run ended; scenario {marker.scenario} starts from a fresh core"
        log.warning("%s: stray_inputs: %s", self.source, detail)
        self.report(
            keys.scenario(marker.scenario),
            "stray_inputs",
            detail,
            count=self.stray_resets,
            counts={"stray_inputs": taken, "stray_resets": self.stray_resets},
            stamp_ns=marker.header.stamp_ns,
        )
        return list(self.new_run(f"scenario {marker.scenario} starts after {taken} stray input(s)") or ())

    def _end_scenario(self, force: bool, publish: bool = True) -> list[Output]:
        """End the pending run if every announced message has arrived (or ``force``); publish or return its
        outputs. The counts it announced are consumed, so early samples of the next run keep theirs."""
        pending = self._pending_end
        if pending is None:
            return []
        missing = sum(max(n - self._arrived[k], 0) for k, n in pending.expected.items())
        if missing and not force:
            return []
        self._pending_end = None
        for k, n in pending.expected.items():
            left = self._arrived[k] - n
            if left > 0:
                self._arrived[k] = left
            else:
                del self._arrived[k]
        if missing:
            self.scenario_ends["incomplete"] += 1
            log.warning("%s: scenario %s ended with %d messages missing", self.source, pending.marker.scenario, missing)
        else:
            self.scenario_ends["complete"] += 1
        try:
            outputs = list(self.on_scenario_end(pending.marker) or ())
        except Exception as exc:
            log.error("%s: on_scenario_end failed:\n%s", self.source, traceback.format_exc())
            self.reject(
                f"{keys.ROOT}/scenario/{pending.marker.scenario}", "internal_error", f"{type(exc).__name__}: {exc}"
            )
            outputs = []
        if publish:
            self._publish_all(outputs)
            return []
        return outputs

    def _publish_all(self, outputs: Iterable[Output]) -> None:
        """Publish each output; one that fails (an encoding the transport refuses, a closed session) is reported
        as ``publish_failed`` and the others still go out: nothing a handler returns ends the process."""
        for out in outputs:
            try:
                self.publish(out.key, out.msg)
            except Exception as exc:
                self.counters.publish_failed += 1
                log.error(
                    "%s: publishing %s on %s failed:\n%s",
                    self.source,
                    type(out.msg).__name__,
                    out.key,
                    traceback.format_exc(),
                )
                self.reject(out.key, "publish_failed", f"{type(out.msg).__name__}: {type(exc).__name__}: {exc}")

    # ----- internals ---------------------------------------------------------------------------
    def _check_monotonic(self, key: str, msg: Message) -> None:
        last = self._last_stamp.get(key)
        if last is not None and msg.header.stamp_ns < last:
            raise InputRejected("stamp_backwards", f"stamp {msg.header.stamp_ns} ns < last {last} ns on {key}")
        self._last_stamp[key] = msg.header.stamp_ns

    def _match(self, key: str) -> Subscription | None:
        """The first subscription whose key expression intersects ``key`` (memoised per key)."""
        return (self._routes.get(key) or self._route(key))[0]

    def _route(self, key: str) -> tuple[Subscription | None, bool]:
        """:meth:`_match` and :func:`_is_scenario_key` of a key not seen yet (remembered for 65,536 keys)."""
        ke = zenoh.KeyExpr(key)
        found = next((s for s in self._subs if zenoh.KeyExpr(s.key_expr).intersects(ke)), None)
        route = (found, _is_scenario_key(key))
        if len(self._routes) < 65536:
            self._routes[key] = route
        return route

    def _enqueue(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if key not in self._wire_keys:
            self._declare_wire_key(key)
        payload = sample.payload
        size = len(payload)
        if size > self._max_payload:  # refused unread: only its size travels to the processing thread
            self._queue.put((key, _Oversized(size), str(sample.encoding), time.time_ns()), 0, self._release_senders)
            return
        self._queue.put((key, payload.to_bytes(), str(sample.encoding), time.time_ns()), size, self._release_senders)

    def _deliver(self, fifo: zenoh.Handler[zenoh.Sample]) -> None:
        """A subscription's delivery thread: wait for a sample (the GIL released), then put it and every sample that
        has arrived behind it into the inbox without letting go of the GIL (``try_recv``); ends once the subscriber
        is undeclared and its FIFO is empty."""
        enqueue, try_recv = self._enqueue, fifo.try_recv
        try:
            for first in fifo:
                sample: zenoh.Sample | None = first
                while sample is not None:
                    try:
                        enqueue(sample)
                    except Exception:  # as Zenoh does for a callback: log it, and the next sample is delivered
                        log.error("%s: delivering a sample failed:\n%s", self.source, traceback.format_exc())
                    sample = try_recv()
        except zenoh.ZError:  # undeclared in the middle of a burst
            pass

    def _declare_wire_key(self, key: str) -> None:
        """Declare a key this service receives samples on (the first ``max_wire_keys`` keys).

        Zenoh charges 3-4 µs of CPU per sample on a subscription with a wildcard whose key is not declared, four
        times what a bare callback costs; once the key is declared, a sample costs what it costs on a subscription to
        that very key (``bench_service_base``, docs/stack.md). The declaration only names the key on this session's
        link: what is delivered, and in which order, does not change."""
        if self.session is None or len(self._wire_keys) >= self.max_wire_keys:
            return
        declared: zenoh.KeyExpr | None = None
        try:
            declared = self.session.declare_keyexpr(key)
        except Exception:  # the declaration only saves CPU: without it the samples still arrive
            log.debug("%s: could not declare key %s", self.source, key, exc_info=True)
        self._wire_keys[key] = declared

    def _subscribe(self, key_expr: str) -> Any:
        """A subscriber on ``key_expr`` whose samples reach the inbox through a FIFO of :data:`FIFO_SAMPLES` and a
        delivery thread of its own (:meth:`_deliver`); end it with :meth:`_unsubscribe`."""
        assert self.session is not None
        sub = self.recovery.declare_subscriber(self.session, key_expr, zenoh.handlers.FifoChannel(FIFO_SAMPLES))
        name = f"deliver-{len(self._delivery)}"
        pump = threading.Thread(target=self._deliver, args=(sub.handler,), name=name, daemon=True)
        pump.start()
        self._delivery[id(sub)] = pump
        return sub

    def _unsubscribe(self, subscribers: Iterable[Any]) -> None:
        """Undeclare ``subscribers``, then wait for their delivery threads: what was in their FIFOs is in the inbox
        (or counted as dropped) after this."""
        subscribers = list(subscribers)
        for d in subscribers:
            with contextlib.suppress(Exception):
                d.undeclare()
        for d in subscribers:
            pump = self._delivery.pop(id(d), None)
            if pump is not None:
                pump.join(timeout=self.settings.enqueue_block_s + 1.0)

    def _declare(self) -> None:
        assert self.session is not None
        self._subs = self.subscriptions()
        scenario_keys = f"{keys.ROOT}/scenario/**"
        keyexprs = [s.key_expr for s in self._subs]
        if not any(zenoh.KeyExpr(k).intersects(zenoh.KeyExpr(scenario_keys)) for k in keyexprs):
            keyexprs.append(scenario_keys)
        for ke in keyexprs:
            self._declared.append(self._subscribe(ke))
        self._declared.append(
            self.session.declare_queryable(keys.status(self.name, self.instance), self._answer_status)
        )
        self._declared.append(self.session.liveliness().declare_token(keys.alive(self.name, self.instance)))
        log.info("%s: up, listening on %s", self.source, ", ".join(keyexprs))

    def _answer_status(self, query: zenoh.Query) -> None:
        body = json.dumps(self.status(), default=str).encode()
        # on this service's own key, never the query's (a wildcard): replies on one key would be consolidated
        query.reply(keys.status(self.name, self.instance), body, encoding=zenoh.Encoding.APPLICATION_JSON)

    def _loop(self) -> None:
        """Process the inbox in arrival order: wait for a sample, then take what has queued behind it without waiting
        (a burst), looking at the clock for the idle housekeeping every ``_BURST`` samples and when the inbox is
        empty."""
        inbox, process = self._queue, self.process
        next_idle = time.monotonic() + 0.2
        while not self._stop.is_set():
            try:
                item = inbox.get(timeout=0.1)
            except queue.Empty:
                item = None
            n = 0
            while item is not None:
                if item is _STOP:
                    return
                process(*item)
                n += 1
                if n % _BURST == 0 and time.monotonic() >= next_idle:
                    break
                try:
                    item = inbox.get()
                except queue.Empty:
                    item = None
            now = time.monotonic()
            if now >= next_idle:
                next_idle = now + 0.2
                self._idle()

    def _report_drops(self) -> None:
        dropped, at_stop = self._queue.take_dropped()
        if dropped:
            self.counters.dropped += dropped
            held = f"full for {self.settings.enqueue_block_s:g} s"
            if at_stop == dropped:
                held = "full when the service stopped"
            elif at_stop:
                held += f" ({at_stop} of them: full when the service stopped)"
            self.report(
                f"{keys.ROOT}/**",
                "queue_full",
                f"{dropped} samples dropped: the inbound queue was {held}",
                count=self.counters.dropped,
                counts={"queue_full": self.counters.dropped},
                level="error",
            )

    def _idle(self) -> None:
        self._report_drops()
        pending = self._pending_end
        if pending is not None and time.monotonic() - self._last_arrival > self.settings.end_wait_s:
            self._end_scenario(force=True)
        try:
            outputs = list(self.on_idle())
        except Exception as exc:
            log.error("%s: on_idle failed:\n%s", self.source, traceback.format_exc())
            self.reject(f"{keys.ROOT}/**", "internal_error", f"on_idle: {type(exc).__name__}: {exc}")
            return
        self._publish_all(outputs)

    def _drain(self) -> None:
        """Process what was queued before the stop, so a SIGTERM does not drop received samples."""
        while True:
            try:
                item = self._queue.get()
            except queue.Empty:
                self._report_drops()
                return
            if item is not _STOP:
                self.process(*item)

    def _shutdown(self) -> None:
        subscribers = [d for d in self._declared if id(d) in self._delivery]  # plain or advanced (shared/recovery.py)
        self._unsubscribe(subscribers)  # stop the inflow first, then finish what already arrived
        try:
            self._drain()
            self._end_scenario(force=True)
            self.on_stop()
        finally:
            for d in reversed(self._declared):
                if d in subscribers:
                    continue
                with contextlib.suppress(Exception):  # already gone with the session
                    d.undeclare()
            for pub in self._publishers.values():
                with contextlib.suppress(Exception):
                    pub.undeclare()
            if self.session is not None:
                self.session.close()
            log.info("%s: stopped", self.source)


class _Oversized(bytes):
    """Stands in for a payload refused unread: empty, but as long as the original for the size check."""

    def __new__(cls, size: int) -> _Oversized:
        obj = super().__new__(cls)
        obj.size = size
        return obj

    size: int

    def __len__(self) -> int:
        return self.size


def _is_scenario_key(key: str) -> bool:
    return key.startswith(_SCENARIO_PREFIX)


_SCENARIO_PREFIX = f"{keys.ROOT}/scenario/"
