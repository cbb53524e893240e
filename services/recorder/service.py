"""The recorder service: everything on a key expression to MCAP, faithfully, with loss counted.

**What is recorded.** Every sample on ``key_expr`` (default ``fixstream/**``):

* a payload that decodes and validates (:func:`shared.codec.unpack` within its size limits, then strict pydantic
  validation) is written as the model's JSON on the channel of its key (:mod:`services.recorder.writer`);
* any other payload is written byte for byte on ``fixstream/rejected/<key>`` with its Zenoh encoding, the reason
  and the detail (:class:`shared.mcap_io.Rejected`), so a replay puts the same bytes back on the same key. Payloads
  over ``max_payload_bytes`` are kept as an envelope without the bytes (``payload_too_large``).

Every message's time in the file is its ``header.stamp_ns`` (the data clock): a recording at ``--rate 0`` and at
``--rate 5`` of the same scenario have the same timeline (docs/recorder.md).

**Loss counted where it happens.** ``(header.source, header.seq)`` per key goes through the base's
:class:`~shared.seq.SeqTracker` (also for rejected payloads whose header unpacks, so a refused message is not a
gap): ``seq.lost`` counts transport gaps only; jumps beyond any plausible loss, repeats and restarts are counted
apart. An in-order message costs one dict look-up; the tracker sees only the exceptions.

**Throughput and back-pressure.** Samples reach the recorder as they reach every service (:mod:`shared.service`):
a Zenoh FIFO per subscription, a delivery thread that moves each burst into the inbox (:class:`shared.inbox.Inbox`,
``queue_size`` samples), and one thread that drains the inbox in batches, validates and hands JSON to the Rust MCAP
writer. When the inbox is full the delivery thread is held, the FIFO fills and holds Zenoh's thread, for up to
``enqueue_block_s`` (30 s; the router waits 60 s before it closes a blocked link), so a blocking publisher slows
down instead of anything being lost; only beyond that are samples dropped, and counted (``queue_full``). (Zenoh's
FIFO itself loses nothing when full: with 4 places and a reader that waits 3 s, 1,000 of 1,000 samples arrive in
order, zenoh-python 1.10.2.) The recorder never queues without bound. After SIGTERM it records what is still in
flight until the inflow is quiet (``stop_drain_s``, :meth:`RecorderService._record_in_flight`). Its status
queryable and liveliness token live on a second session, whose link the data's back-pressure never holds, so it
answers at once however far behind the data is.

**Crash bound.** In memory at any time: the inbox (≤ ``queue_size`` samples) and the open chunk (≤
``chunk_flush_s`` of wall time, checked after every batch, and ≤ ``chunk_size_bytes``). A SIGKILL loses at most
that; everything older is in complete chunks on disk (status ``durable``).

**Self-describing files.** Metadata records ``fixstream.recorder`` (version, configuration, what the time fields
mean), ``fixstream.run`` (scenario, seed, run index, player, origin; from the player's start marker) and
``fixstream.services`` (every service's configuration from its status queryable, asked at the start marker until
every live service answered, and how many did); the
scenario YAML and its maps as attachments, looked up only inside the scenario directory
(:mod:`services.recorder.run_context`).

**Its own diagnostics are bounded.** Rejections and seq events are aggregated: at most one diagnostic per reason
per ``diag_interval_s`` (with the counts), whatever the flood.

Status (``fixstream/status/recorder/<instance>``) adds ``written``, ``rejected_recorded``, ``durable``, ``lost``,
``seq_gaps``, ``seq_jumps``, ``seq_resets``, ``write_errors``, ``write_failing``, ``last_write_error``,
``unwritten`` (a write error pauses writing for 1-30 s; the recorder then exits 1), ``files_written``, ``recent_files``,
``current_file``, ``fifo`` (capacity, the largest backlog drained at once) and ``runs`` to the base's.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
from collections import Counter, deque
from collections.abc import Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, ClassVar, cast

import zenoh

from schemas import Message, ScenarioMarker
from schemas.base import MAX_STAMP_NS
from shared import codec, keys
from shared.foxglove.convert import Converter
from shared.foxglove.frames import FrameContext
from shared.foxglove.recording import FoxgloveChannels
from shared.mcap_io import Rejected
from shared.service import _STOP, PLAYER_PREFIX, Output, Service, Subscription
from shared.session import open_session
from shared.settings import ZenohSettings
from shared.status import STATUS_ATTEMPTS, AliveTokens, collect_statuses

from .run_context import RunContext, recorder_metadata, run_context, services_metadata
from .settings import RecorderSettings
from .writer import RotatingMcapWriter

log = logging.getLogger("fixstream.recorder")

#: samples taken from the FIFO before the writer's flush and rotation are checked again
_BATCH = 4096
#: start markers whose scenario look-up may be in flight at once (a flood of markers waits for the oldest)
_MAX_LOOK_UPS = 8
#: (key, source) pairs whose next seq is remembered on the fast path, at most
_MAX_PAIRS = 65_536
_SCENARIO_KEYS = f"{keys.ROOT}/scenario/**"
_SCENARIO_PREFIX = f"{keys.ROOT}/scenario/"
#: after a write error nothing is written for this long (doubling per further error up to the maximum), s
_WRITE_BACKOFF_MIN_S = 1.0
_WRITE_BACKOFF_MAX_S = 30.0
#: an encoding not looked up yet (None means: looked up, not a fixstream encoding)
_UNSEEN: Any = object()
#: a player's end marker is held this long before the run's tails are checked against it (what the player sent
#: before it and is still in flight arrives first; markers may come through a subscription of their own), s
_END_CHECK_S = 1.0
#: player sources whose start marker opened a run here, remembered at most (a flood of sources forgets the oldest)
_MAX_RUNS_OPEN = 1024


class RecorderService(Service):
    """Records a key expression to rotating MCAP files; see the module docstring."""

    name: ClassVar[str] = "recorder"
    #: the recorder aggregates its own diagnostics (one per reason per diag_interval_s); this only caps bursts
    diag_burst: ClassVar[int] = 20
    diag_rate_hz: ClassVar[float] = 10.0

    def __init__(self, settings: RecorderSettings, zenoh_settings: ZenohSettings | None = None) -> None:
        super().__init__(settings, zenoh_settings)
        self.config = settings
        self.writer = RotatingMcapWriter(
            settings.out_dir,
            prefix=settings.file_prefix,
            compression=settings.compression,
            chunk_size_bytes=settings.chunk_size_bytes,
            chunk_flush_s=settings.chunk_flush_s,
            rotate_size_bytes=settings.rotate_size_bytes,
            rotate_duration_s=settings.rotate_duration_s,
        )
        self.writer.put_metadata("fixstream.recorder", recorder_metadata(self.source, settings.model_dump(mode="json")))
        self.write_errors = 0
        #: a write failed: nothing is written before this monotonic time (the next attempt; see _write_failed)
        self._write_paused_until: float | None = None
        self._write_backoff_s = 0.0
        #: messages not written because the disk failed (counted while writing is paused)
        self.unwritten = 0
        self.last_write_error: str | None = None
        #: next expected seq per (key, header.source): the fast path of the seq check
        self._next_seq: dict[tuple[str, str], int] = {}
        #: decoded model per encoding string (None: not a fixstream encoding)
        self._models: dict[str, type[Message] | None] = {}
        #: the data clock: stamp of the last valid message (what a rejected payload without a stamp is filed at)
        self.data_clock_ns = 0
        self.fifo_peak = 0
        self.runs: Counter[str] = Counter()
        self.current_run: RunContext | None = None
        self._diag_since: Counter[str] = Counter()
        self._diag_example: dict[str, tuple[str, str]] = {}
        #: player sources whose start marker this recorder saw (their end marker's counts can be checked)
        self._runs_open: dict[str, None] = {}
        #: end markers waiting for their check: (source, published per key, when it is due on the monotonic clock)
        self._ends: deque[tuple[str, dict[str, int], float]] = deque()
        #: messages a player's end marker counts that never arrived after the last one that did (no seq shows them)
        self.lost_at_end = 0
        #: run ends at which some were missing (the diagnostic's count)
        self.ends_with_loss = 0
        self._records_key: dict[str, bool] = {}
        self._recorded_expr = zenoh.KeyExpr(settings.key_expr)
        #: when the next aggregated diagnostics are due: one interval after the start, and after each flush
        self._next_diag = time.monotonic() + settings.diag_interval_s
        self._status_thread: threading.Thread | None = None
        #: start markers' scenario look-ups, in marker order, on a worker thread: a first look-up imports the simulators
        #: and takes seconds (1.7 s for the demo on an idle machine, 7 s with two stacks at once), which the loop
        #: spent not recording while Zenoh held the stack back; the loop writes each result once it is done
        self._look_ups: deque[Future[RunContext]] = deque()
        self._look_up_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="recorder-scenario")
        self._status_replies: tuple[list[dict[str, Any]], list[str]] | None = None
        #: services whose status answered the last start marker's query (their configuration is in the file)
        self.services_seen = 0
        self._control: zenoh.Session | None = None
        #: set once what was in flight at the stop is recorded (:meth:`_record_in_flight`): until then a delivery
        #: thread held by a full inbox waits instead of dropping
        self._release_senders = threading.Event()
        #: the liveliness tokens alive now (what a start marker's status query waits for)
        self.alive = AliveTokens()
        #: the Foxglove scene and map channels (FIXSTREAM_RECORDER_FOXGLOVE), converted from what is written
        self.foxglove: FoxgloveChannels | None = None
        if settings.foxglove:
            self.foxglove = FoxgloveChannels(Converter(FrameContext()))

    # ----- the base's hooks (offline use: Service.process -> the raw handler) -------------------------
    def subscriptions(self) -> list[Subscription]:
        return [Subscription(key_expr=self.config.key_expr, raw_handler=self._raw)]

    def _raw(self, key: str, payload: bytes, encoding: str) -> Iterable[Output]:
        self.on_sample(key, payload, encoding)
        return ()

    def on_stop(self) -> None:
        """Finalise the current file (summary, footer, fsync)."""
        try:
            path = self.writer.finish()
            if path is not None:
                log.info("%s: finalised %s", self.source, path)
        except OSError as exc:
            self._write_failed(self.config.key_expr, exc)
        finally:
            self._list_files()

    def _list_files(self) -> None:
        """Every file this recorder wrote, one path a line, in ``files_list`` (what ``fixstream up`` reports)."""
        target = self.config.files_list
        if target is None:
            return
        try:
            target.write_text("".join(f"{p}\n" for p in self.writer.files_written))
        except OSError as exc:
            log.error("%s: cannot write the list of files to %s: %s", self.source, target, exc)

    def status_extra(self) -> dict[str, Any]:
        current = self.writer.current_path
        ev = self.seq.events
        return {
            "written": self.writer.messages_written,
            "rejected_recorded": self.writer.rejected_written,
            "durable": self.writer.durable,
            "lost": self.seq.lost,
            "lost_at_end": self.lost_at_end,
            "seq_gaps": ev["seq_gap"],
            "seq_jumps": ev["seq_jump"],
            "seq_resets": ev["seq_reset"],
            "duplicates": ev["duplicate"],
            "write_errors": self.write_errors,
            "write_failing": self._write_paused_until is not None,
            "last_write_error": self.last_write_error,
            "unwritten": self.unwritten,
            "files_written": self.writer.files_finalised,
            "recent_files": [str(p) for p in self.writer.files_written[-10:]],
            "current_file": str(current) if current is not None else None,
            "unflushed_age_s": round(self.writer.unflushed_age_s, 3),
            "fifo": {"capacity": self.config.queue_size, "peak_backlog": self.fifo_peak},
            "data_clock_ns": self.data_clock_ns,
            "runs": dict(self.runs),
            "services_seen": self.services_seen,
            "foxglove_written": self.foxglove.written if self.foxglove is not None else None,
            "foxglove_errors": dict(self.foxglove.errors) if self.foxglove is not None else None,
        }

    # ----- serving: FIFO handler, batches, no per-sample callback --------------------------------------
    def run(self) -> int:
        """Open the session, record until stopped (SIGTERM/SIGINT), finalise the file, close. Exit code 0; 1 when a
        write failed (the recording is incomplete or missing: a stack, local or in containers, must not end with 0)."""
        if not self._open_alone():  # a second recorder of this name would count its losses as the other's
            return 0
        assert self.session is not None
        subs: list[Any] = []
        declared: list[Any] = []
        try:
            subs.append(self._subscribe(self.config.key_expr))  # FIFO + delivery thread into the inbox, as a service
            if not zenoh.KeyExpr(self.config.key_expr).intersects(zenoh.KeyExpr(_SCENARIO_KEYS)):
                # markers are not recorded then, but they still name the run in the metadata
                subs.append(
                    self.recovery.declare_subscriber(self.session, _SCENARIO_KEYS, zenoh.handlers.FifoChannel(64))
                )
            # status and liveliness on a session of their own: its link is never held by the data FIFO's
            # back-pressure, so the recorder answers at once however far behind its data is
            self._control = control = open_session(self.zenoh_settings)
            declared.append(control.declare_queryable(keys.status(self.name, self.instance), self._answer_status))
            declared.append(control.liveliness().declare_token(keys.alive(self.name, self.instance)))
            # which services are alive, known before any start marker asks them for their configuration
            declared.append(self.alive.watch(control))
            log.info("%s: up, recording %s to %s", self.source, self.config.key_expr, self.writer.out_dir)
            self._serve(subs)
        finally:
            self._close(subs, declared)
        if self.write_errors:
            log.error(
                "%s: %d write error(s), %d message(s) not written, %d file(s) finalised; last: %s",
                self.source,
                self.write_errors,
                self.unwritten,
                self.writer.files_finalised,
                self.last_write_error,
            )
            return 1
        return 0

    def _serve(self, subs: list[Any]) -> None:
        markers = subs[1].handler if len(subs) > 1 else None
        while not self._stop.is_set():
            n = self._take(_BATCH, wait_s=0.01)
            if markers is not None:
                self._drain_markers(markers)
            self._housekeeping()
            if n == 0:
                self._report_drops()

    def _take(self, budget: int, wait_s: float | None = None) -> int:
        """Record up to ``budget`` samples waiting in the inbox (waiting up to ``wait_s`` for the first one);
        returns how many."""
        inbox, on_sample = self._queue, self.on_sample
        backlog = inbox.qsize()
        if backlog > self.fifo_peak:
            self.fifo_peak = backlog
        n = 0
        while n < budget:
            try:
                item = inbox.get(wait_s if n == 0 else None)
            except queue.Empty:
                break
            if item is _STOP:
                break
            key, payload, encoding, _ = item
            on_sample(key, payload, encoding)
            n += 1
        return n

    def _drain_markers(self, handler: Any) -> None:
        while (sample := _try_recv(handler)) is not None:
            with contextlib.suppress(codec.DecodeError):
                msg = codec.decode(sample.payload.to_bytes(), str(sample.encoding))
                if isinstance(msg, ScenarioMarker):
                    self._marker(msg)

    def _close(self, subs: list[Any], declared: list[Any]) -> None:
        """Stop the inflow, record what already arrived (at most a FIFO's worth) and the recorder's final diagnostics,
        finalise, close the session."""
        own_key = keys.diag(self.name, self.instance)
        own: Any = None
        if self.session is not None and zenoh.KeyExpr(self.config.key_expr).intersects(zenoh.KeyExpr(own_key)):
            # only the recorder's own diagnostics still come in: its final counts (published below) are recorded
            with contextlib.suppress(Exception):
                own = self._subscribe(own_key)
        try:
            self._record_in_flight(subs)
        finally:
            self._release_senders.set()
        self._unsubscribe(subs)
        try:
            try:
                while self._take(_BATCH):
                    pass
                self._report_drops()
                self._housekeeping(final=True)
                if own is not None:
                    self._record_own_diagnostics(own_key)
            finally:
                if own is not None:
                    self._unsubscribe([own])
            while self._take(_BATCH):
                pass
            self._await_services()
            self._open_looked_up(wait=True)
            self._look_up_pool.shutdown()
            self.on_stop()
        finally:
            for d in reversed(declared):
                with contextlib.suppress(Exception):
                    d.undeclare()
            for pub in self._publishers.values():
                with contextlib.suppress(Exception):
                    pub.undeclare()
            for session in (self._control, self.session):
                if session is not None:
                    with contextlib.suppress(Exception):
                        session.close()
            log.info("%s: stopped", self.source)

    def _record_in_flight(self, subs: list[Any]) -> None:
        """After the stop, before the subscription ends: record what still arrives (samples a full inbox held back
        in Zenoh, the estimators' last outputs as they stop) until nothing has come for ``stop_quiet_s``, at most
        ``stop_drain_s``. A recorder stopped while behind used to drop all of it (``queue_full``)."""
        markers = subs[1].handler if len(subs) > 1 else None
        quiet_s = self.config.stop_quiet_s
        now = last = time.monotonic()
        deadline = now + self.config.stop_drain_s
        while now < deadline and now - last < quiet_s:
            if self._take(_BATCH, wait_s=min(0.01, quiet_s)):
                last = time.monotonic()
            if markers is not None:
                self._drain_markers(markers)
            self._housekeeping()
            now = time.monotonic()

    def _await_services(self) -> None:
        """A status query still in flight (a start marker just before the stop): its answers go into the file."""
        thread = self._status_thread
        if thread is not None and thread.is_alive():
            thread.join(timeout=STATUS_ATTEMPTS * 2 * self.config.status_timeout_s)
        self._write_services()

    def _write_services(self) -> None:
        """The services' configuration, once the start marker's status query has its answers."""
        if self._status_replies is not None:
            (replies, alive), self._status_replies = self._status_replies, None
            self.services_seen = len(replies)
            self.writer.put_metadata("fixstream.services", services_metadata(replies, alive))

    def _record_own_diagnostics(self, key: str, timeout_s: float = 2.0) -> None:
        """Wait (bounded) until the diagnostics this recorder published on ``key`` came back through its own
        subscription and are written."""
        published = self._seq.get(key, 0)
        deadline = time.monotonic() + timeout_s
        while self._next_seq.get((key, self.source), 0) < published and time.monotonic() < deadline:
            self._take(_BATCH, wait_s=0.02)

    def _housekeeping(self, final: bool = False) -> None:
        """After every batch: the writer's flush and rotation, the services' configuration, the diagnostics."""
        try:
            self.writer.poll()
        except OSError as exc:
            self._write_failed(self.config.key_expr, exc)
        if self.writer.failed is not None:
            self._write_failed(self.config.key_expr, self.writer.failed)
        self._write_services()
        self._open_looked_up()
        now = time.monotonic()
        # due, and nothing left in the inbox that could still be the run's (markers may come on their own subscription)
        while self._ends and (final or (self._ends[0][2] <= now and not self._queue.qsize())):
            self._check_end(*self._ends.popleft()[:2])
        if final or now >= self._next_diag:
            self._next_diag = now + self.config.diag_interval_s
            self._flush_diagnostics()

    # ----- one sample ------------------------------------------------------------------------------------
    def on_sample(self, key: str, payload: bytes, encoding: str) -> None:
        """Record one sample: valid -> its channel; anything else -> ``fixstream/rejected/<key>``."""
        c = self.counters
        c.received += 1
        if len(payload) > self._max_payload:
            detail = f"{len(payload)} bytes > max_payload_bytes {self._max_payload}: bytes not kept"
            self._rejected(key, b"", encoding, "payload_too_large", detail, None)
            return
        model = self._models.get(encoding, _UNSEEN)
        if model is _UNSEEN:
            model = self._model_of(encoding)
        obj: Any = None
        try:
            if model is None:
                codec.model_for_encoding(encoding)  # raises the precise DecodeError
                raise codec.DecodeError("bad_encoding", encoding)
            obj = codec.unpack(payload)
            msg = codec.validate(model, obj)
        except codec.DecodeError as exc:
            self._rejected(key, payload, encoding, exc.reason, exc.detail, obj)
            return
        h = msg.header
        pair = (key, h.source)
        if self._next_seq.get(pair) == h.seq:
            self._next_seq[pair] = h.seq + 1
        else:
            self._seq_event(pair, h.seq)
        if type(msg) is ScenarioMarker:
            self._marker(msg)
        stamp = h.stamp_ns
        if self._write_paused_until is not None and self._write_paused():
            return
        try:
            self.writer.write_json(key, model, model.__pydantic_serializer__.to_json(msg), stamp)
            if self.foxglove is not None:
                self.foxglove.write(self.writer, key, msg, 0)
        except OSError as exc:
            self._write_failed(key, exc)
            return
        if stamp > self.data_clock_ns or type(msg) is ScenarioMarker:
            self.data_clock_ns = stamp
        c.accepted += 1

    def _model_of(self, encoding: str) -> type[Message] | None:
        try:
            model: type[Message] | None = codec.model_for_encoding(encoding)
        except codec.DecodeError:
            model = None
        if len(self._models) < 4096:  # encodings come from the network: bound what is remembered
            self._models[encoding] = model
        return model

    def _rejected(self, key: str, payload: bytes, encoding: str, reason: str, detail: str, obj: Any) -> None:
        """Count, record byte for byte on fixstream/rejected/<key>, and note it for the aggregated diagnostic."""
        c = self.counters
        c.rejected += 1
        c.rejected_by_reason[reason] += 1
        c.last_error, c.last_error_key = f"{reason}: {detail}", key
        stamp = self.data_clock_ns
        if obj is None and payload:
            with contextlib.suppress(codec.DecodeError):
                obj = codec.unpack(payload)
        header = obj.get("header") if type(obj) is dict else None
        if type(header) is dict:
            s = header.get("stamp_ns")
            if type(s) is int and 0 <= s <= MAX_STAMP_NS:
                stamp = s
            sequenced = codec.header_of(obj)
            if sequenced is not None:
                source, seq, _ = sequenced
                pair = (key, source)
                if self._next_seq.get(pair) == seq:
                    self._next_seq[pair] = seq + 1
                else:
                    self._seq_event(pair, seq)
        self._diag_since[reason] += 1
        self._diag_example[reason] = (key, detail)
        if self._write_paused_until is not None and self._write_paused():
            return
        try:
            self.writer.write_rejected(Rejected(key, encoding, reason, detail[:1000], payload, time.time_ns()), stamp)
        except OSError as exc:
            self._write_failed(key, exc)

    def _seq_event(self, pair: tuple[str, str], seq: int) -> None:
        """The seq check's slow path: hand the exception to the base's tracker, primed with what was expected."""
        key, source = pair
        expected = self._next_seq.get(pair)
        if expected is None and len(self._next_seq) >= _MAX_PAIRS:
            self._next_seq.pop(next(iter(self._next_seq)))
        self._next_seq[pair] = seq + 1
        if expected is None:
            if seq > 0 and source in self._runs_open and not key.startswith(_SCENARIO_PREFIX):
                expected = 0  # a player's stream in a run whose start this recorder saw counts from 0: head lost
            else:
                return  # the first message of a pair only sets the reference (a subscriber that joined late)
        tracker = self.seq
        tracker.forget(key, source)
        tracker.check(key, source, expected - 1)
        check = tracker.check(key, source, seq)
        if check.event in ("seq_gap", "seq_jump", "seq_reset", "duplicate"):
            self._diag_since[check.event] += 1
            what = f"{check.missing} lost" if check.event == "seq_gap" else check.event
            who = source or "<no source>"
            self._diag_example[check.event] = (key, f"{what} on {key} from {who}: expected {expected}, got {seq}")

    # ----- scenario runs ---------------------------------------------------------------------------------
    def _marker(self, marker: ScenarioMarker) -> None:
        """A player's start marker: its seq counts restart; the run's metadata, attachments and services' config."""
        source = marker.header.source
        if not source.startswith(PLAYER_PREFIX):
            return  # recorded as it came, but only a player's markers open and close a run
        if marker.event == "end":
            if source in self._runs_open:
                self._ends.append((source, dict(marker.published), time.monotonic() + _END_CHECK_S))
            return
        if marker.event != "start":
            return
        pending, self._ends = self._ends, deque()
        for end in pending:  # this source's last run is checked now, before its seq counts restart
            if end[0] == source:
                self._check_end(*end[:2])
            else:
                self._ends.append(end)
        self._runs_open.pop(source, None)
        if len(self._runs_open) >= _MAX_RUNS_OPEN:
            self._runs_open.pop(next(iter(self._runs_open)))
        self._runs_open[source] = None
        self.seq.forget_source(source)
        for pair in [p for p in self._next_seq if p[1] == source]:
            del self._next_seq[pair]
        self.runs[marker.scenario] += 1
        # ask first: the scenario's look-up below takes seconds on its first run (measured 1.7 s for the demo on an
        # idle machine), by which time a --rate 0 run may be over and its services stopped (it missed 5 of 9)
        self._ask_services()
        directories = [self.config.scenarios_dir or _default_scenarios_dir()]
        args = (marker, self.runs[marker.scenario], directories, self.config.max_attachment_bytes)
        if self.foxglove is not None:  # its converter must know the run's frames before the run's next message
            self._open_run(run_context(*args))
            return
        while len(self._look_ups) >= _MAX_LOOK_UPS:  # a flood of markers waits for the oldest: memory stays bounded
            self._open_run(self._look_ups.popleft())
        self._look_ups.append(self._look_up_pool.submit(run_context, *args))

    def _check_end(self, source: str, published: dict[str, int]) -> None:
        """A player's end marker against what arrived: on every key it counts that this recorder subscribes to, the
        messages after the last seq that arrived (``published[key]`` minus the next seq expected) never came. The
        seq check cannot see them (no later message shows the gap): they are counted here, as ``lost_at_end``."""
        self._runs_open.pop(source, None)
        missing: dict[str, int] = {}
        for key, n in published.items():
            if n > 0 and self._records(key):
                late = n - self._next_seq.get((key, source), 0)
                if late > 0:
                    missing[key] = late
        if not missing:
            return
        total = sum(missing.values())
        self.lost_at_end += total
        self.ends_with_loss += 1
        self._diag_since["lost_at_end"] += 1
        worst = sorted(missing.items(), key=lambda kv: (-kv[1], kv[0]))[:3]
        listed = ", ".join(f"{n} on {key}" for key, n in worst)
        more = f" and {len(missing) - 3} other key(s)" if len(missing) > 3 else ""
        detail = f"{total} message(s) {source} counted in its end marker never arrived: {listed}{more}"
        self._diag_example["lost_at_end"] = (worst[0][0], detail)

    def _records(self, key: str) -> bool:
        """Whether ``key`` (from an end marker: any string) is one this recorder subscribes to."""
        known = self._records_key.get(key)
        if known is None:
            try:
                known = self._recorded_expr.intersects(zenoh.KeyExpr(key))
            except Exception:  # not a key expression: nothing was ever published on it
                known = False
            if len(self._records_key) < 65_536:
                self._records_key[key] = known
        return known

    def _open_run(self, run: RunContext | Future[RunContext]) -> None:
        """A start marker's run (or the look-up that finds it, waited for): its metadata and attachments in the
        file, and its frames for the Foxglove channels."""
        if isinstance(run, Future):
            try:
                run = run.result()
            except Exception:  # a look-up that fails leaves the run without attachments, never the recording
                log.exception("%s: the scenario look-up of a start marker failed", self.source)
                return
        self.current_run = run
        self.writer.put_metadata("fixstream.run", run.metadata())
        for name, media_type, data in run.attachments:
            self.writer.put_attachment(name, media_type, data, run.stamp_ns)
        if self.foxglove is not None:
            self.foxglove.converter = (
                Converter.for_scenario(run.loaded) if run.loaded is not None else Converter(FrameContext())
            )

    def _open_looked_up(self, wait: bool = False) -> None:
        """Write the runs whose look-up is done, in marker order (``wait``: all of them, waiting)."""
        while self._look_ups and (wait or self._look_ups[0].done()):
            self._open_run(self._look_ups.popleft())

    def _ask_services(self) -> None:
        """Query every service's status in the background; the loop writes the answers as metadata."""
        session = self._control or self.session  # the control link: replies are not held behind data
        if session is None or (self._status_thread is not None and self._status_thread.is_alive()):
            return

        def ask() -> None:
            t0 = time.monotonic()
            replies, alive = collect_statuses(session, self.config.status_timeout_s, self.alive.now)
            log.info(
                "%s: %d of %d live services answered the status query (%.1f s)",
                self.source,
                len(replies),
                len(alive),
                time.monotonic() - t0,
            )
            self._status_replies = replies, alive

        self._status_thread = threading.Thread(target=ask, name="recorder-status-query", daemon=True)
        self._status_thread.start()

    # ----- diagnostics -----------------------------------------------------------------------------------
    def _flush_diagnostics(self) -> None:
        """One diagnostic per reason that happened since the last: how many, and the last example."""
        if not self._diag_since:
            return
        pending, self._diag_since = self._diag_since, Counter()
        for reason, n in pending.items():
            key, detail = self._diag_example.get(reason, (self.config.key_expr, ""))
            if reason == "write_error":
                total, counts = self.write_errors, {"write_error": self.write_errors}
                text = f"{n} write error(s); the file was closed (readable up to its last chunk); last: {detail}"
            elif reason == "lost_at_end":
                total, counts = self.ends_with_loss, {**self.seq.as_dict(), "lost_at_end": self.lost_at_end}
                text = f"{n} run end(s) with messages missing at the tail; last: {detail}"
            elif reason in self.counters.rejected_by_reason:
                total, counts = self.counters.rejected_by_reason[reason], dict(self.counters.rejected_by_reason)
                text = f"{n} payload(s) rejected ({reason}) and recorded raw on fixstream/rejected/...; last: {detail}"
            else:
                total, counts = self.seq.events[reason], self.seq.as_dict()
                text = f"{n} seq event(s) ({reason}); last: {detail}"
            self.report(key, reason, text, count=total, counts=counts)

    def _write_failed(self, key: str, exc: OSError) -> None:
        """A disk error: drop the current file (readable up to its last chunk), report it, and write nothing for a
        while (1 s, doubling to 30 s): a directory that cannot be written is tried once per pause, not once per
        message (each attempt would be a new file name); the messages of the pause are counted (``unwritten``)."""
        self.write_errors += 1
        path = self.writer.abandon()
        self._write_backoff_s = min(_WRITE_BACKOFF_MAX_S, max(_WRITE_BACKOFF_MIN_S, 2 * self._write_backoff_s))
        self._write_paused_until = time.monotonic() + self._write_backoff_s
        where = path if path is not None else self.writer.out_dir
        log.error(
            "%s: writing %s failed: %s (%d message(s) not written so far; next attempt in %g s)",
            self.source,
            where,
            exc,
            self.unwritten,
            self._write_backoff_s,
        )
        self.last_write_error = f"{where}: {exc}"
        self.counters.last_error, self.counters.last_error_key = f"write_error: {where}: {exc}", key
        self._diag_since["write_error"] += 1
        self._diag_example["write_error"] = (key, f"{where}: {exc}")

    def _write_paused(self) -> bool:
        """Whether writing is paused after a write error (the message is then counted, not written)."""
        until = self._write_paused_until
        if until is not None and time.monotonic() < until:
            self.unwritten += 1
            return True
        self._write_paused_until = None  # try again (a further error pauses twice as long)
        return False


def _try_recv(handler: Any) -> Any:
    try:
        return handler.try_recv()
    except zenoh.ZError:  # undeclared and empty
        return None


def _default_scenarios_dir() -> Path:
    from services.player.scenario import default_dir

    return default_dir()


def build() -> RecorderService:
    """The recorder configured from ``FIXSTREAM_RECORDER_*`` and ``FIXSTREAM_ZENOH_*``."""
    settings = cast(RecorderSettings, RecorderSettings.load())
    return RecorderService(settings)
