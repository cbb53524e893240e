"""Stopping a stack that is still behind loses nothing it was sent.

Found with two demo stacks run at once on the 2 cores: one recording held 4,099 of 6,601 messages, with the
diagnostic "2502 samples dropped: the inbound queue was full for 30 s" in a run that lasted 3 s. The recorder was
behind the player (its inbox full, Zenoh holding the rest), ``fixstream up`` stopped the stack 1 s after the
player's end, and the recorder dropped what was still in flight when its SIGTERM came. Now

* ``fixstream up`` stops the stack only once it has settled (every ``fixstream run`` service answers its status
  with an empty inbox and no run end pending, twice in a row with nothing received in between; at most
  ``--drain`` seconds);
* a recorder that gets SIGTERM records what is still in flight until nothing has come for ``stop_quiet_s`` (at
  most ``stop_drain_s``) before it ends its subscription (compose stops every container when the player exits);
* a drop at the stop is named as one, not as a queue full for ``enqueue_block_s``.

Real processes and a real router: the recorder is made to fall behind by SIGSTOP, which is what a starved process
looks like from the outside.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import threading
import time
from pathlib import Path

from conftest import REPO, fixstream_cmd
from hypothesis import given, settings
from hypothesis import strategies as st
from recorder_support import Recorder, by_topic, recorder, records_of
from stack_support import stack_env
from test_scenario_files import nav_scenario, write_scenario

from schemas import Depth, Diagnostic, Header
from shared.inbox import Inbox
from shared.mcap_io import decode_record, iter_records, recording_files
from shared.status import quiet_counts

KEY = "fixstream/sensor/late/depth/d0"


def _depth(seq: int) -> Depth:
    return Depth(header=Header(stamp_ns=seq * 1_000_000, source="test/late", seq=seq), depth_m=10.0 + seq * 1e-3)


def test_a_recorder_stopped_while_behind_records_what_was_in_flight(router: str, tmp_path: Path) -> None:
    """SIGTERM reaches a recorder with a full inbox (16 samples) and 3,000 samples held back in Zenoh: every one
    is recorded, in order, and nothing is reported dropped. (Before: most were dropped as ``queue_full``.)"""
    n = 3000
    with recorder(router, tmp_path, instance="late", FIXSTREAM_RECORDER_QUEUE_SIZE="16") as rec:
        rec.publisher(KEY)  # matched before the recorder stops
        rec.proc.send_signal(signal.SIGSTOP)
        sender = threading.Thread(target=lambda: [rec.send(KEY, _depth(i)) for i in range(n)], daemon=True)
        try:
            sender.start()
            time.sleep(1.0)  # the samples pile up in the router and the sockets (the sender may block: BLOCK)
            rec.proc.send_signal(signal.SIGTERM)  # pending until the process runs again
        finally:
            rec.proc.send_signal(signal.SIGCONT)
        sender.join(timeout=30)
        assert not sender.is_alive(), "the sender never finished: the recorder held it back"
        assert rec.proc.wait(timeout=30) == 0, rec.log()
    topics = by_topic(records_of(recording_files(rec.out_dir)))
    seqs = [m.header.seq for m in topics.get(KEY, [])]
    assert seqs == list(range(n)), (len(seqs), rec.log())
    diags = [d for msgs in topics.values() for d in msgs if isinstance(d, Diagnostic) and d.reason == "queue_full"]
    assert diags == [], diags


def test_a_recorder_fed_forever_still_stops_within_its_drain_bound(router: str, tmp_path: Path) -> None:
    """A publisher that never stops cannot keep a stopped recorder alive: it ends within ``stop_drain_s`` (1 s
    here) plus its close, exit 0, with a finalised file holding a gap-free prefix of what was sent."""
    stop = threading.Event()
    sent = [0]

    def feed(rec: Recorder) -> None:
        i = 0
        while not stop.is_set():
            rec.send(KEY, _depth(i))
            i += 1
            sent[0] = i
            time.sleep(0.0005)

    with recorder(router, tmp_path, instance="fed", FIXSTREAM_RECORDER_STOP_DRAIN_S="1.0") as rec:
        rec.publisher(KEY)
        feeder = threading.Thread(target=feed, args=(rec,), daemon=True)
        feeder.start()
        try:
            rec.wait_status(lambda s: s["counters"]["received"] > 100)
            t0 = time.monotonic()
            rec.proc.send_signal(signal.SIGTERM)
            rc = rec.proc.wait(timeout=30)
            elapsed = time.monotonic() - t0
        finally:
            stop.set()
            feeder.join(timeout=10)
    assert rc == 0, rec.log()
    # 1 s of drain, then the close (final diagnostics, the services' metadata wait, the file's summary)
    assert elapsed < 1.0 + 6.0, elapsed
    seqs = [m.header.seq for m in by_topic(records_of(recording_files(rec.out_dir))).get(KEY, [])]
    assert seqs == list(range(len(seqs))) and 100 < len(seqs) <= sent[0], (len(seqs), sent[0])


def test_up_waits_for_a_stalled_recorder_before_stopping_the_stack(tmp_path: Path) -> None:
    """``fixstream up`` with its recorder stalled (SIGSTOP) from the player's first message until 3 s after the
    player's end: the stack is stopped only after the recorder ran again and caught up, and the recording holds
    every message the player published. (Before: the stop came 1 s after the player's end, while the recorder
    was still stalled, and the recording lost what was held back.)"""
    recordings = tmp_path / "recordings"
    scenario = write_scenario(tmp_path, nav_scenario("late", duration_s=300.0))  # waits for the recorder only
    proc = subprocess.Popen(
        fixstream_cmd("up", "router", "recorder", "player", "--recordings", str(recordings), "--router-port", "0"),
        cwd=REPO,
        env={**stack_env(scenario), "FIXSTREAM_NO_COLOR": "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: list[tuple[float, str]] = []  # each line with the time it was read (the reading never sleeps)
    recorder_pid: int | None = None
    resumed_at: list[float] = []

    def resume() -> None:
        assert recorder_pid is not None
        resumed_at.append(time.monotonic())
        os.kill(recorder_pid, signal.SIGCONT)

    timer: threading.Timer | None = None
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append((time.monotonic(), line))
            if (m := re.search(r"\[up\] recorder started, pid (\d+)", line)) is not None:
                recorder_pid = int(m.group(1))
            elif "fixstream.player: alive:" in line:  # it saw the recorder and starts publishing
                assert recorder_pid is not None
                os.kill(recorder_pid, signal.SIGSTOP)
            elif "[up] player exited" in line:
                timer = threading.Timer(3.0, resume)
                timer.start()
        rc = proc.wait(timeout=120)
    finally:
        if timer is not None:
            timer.join()
        if recorder_pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(recorder_pid, signal.SIGCONT)
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    log = "".join(text for _, text in lines)
    assert rc == 0, log[-4000:]
    assert resumed_at, log[-4000:]
    stops = [t for t, text in lines if "[up] stopping recorder" in text]
    assert stops and stops[0] > resumed_at[0], log[-4000:]  # not while it was stalled
    published = int(re.search(r"published (\d+) messages", log).group(1))  # type: ignore[union-attr]
    files = recording_files(recordings)
    from_player = [r for f in files for r in iter_records(f) if decode_record(r).header.source.startswith("player/")]
    markers = 2  # the start and end markers are published outside the player's count
    assert len(from_player) == published + markers, (len(from_player), published, log[-3000:])


# ----- the pieces, without processes --------------------------------------------------------------------------------
def _status(who: str, depth: int = 0, pending: bool = False, received: int = 0) -> dict[str, object]:
    service, instance = who.split("/")
    return {
        "service": service,
        "instance": instance,
        "queue_depth": depth,
        "scenario": {"end_pending": pending, "ends": {}},
        "counters": {"received": received},
    }


@settings(max_examples=200, deadline=None)
@given(
    st.dictionaries(
        st.sampled_from(["a/1", "b/1", "c/2", "recorder/main"]),
        st.tuples(st.integers(0, 3), st.booleans(), st.integers(0, 10**9)),
        max_size=4,
    ),
    st.sets(st.sampled_from(["a/1", "b/1", "c/2", "recorder/main", "x/9"])),
)
def test_quiet_counts_is_none_unless_every_expected_service_is_idle(
    answers: dict[str, tuple[int, bool, int]], expected: set[str]
) -> None:
    statuses = [_status(w, d, p, r) for w, (d, p, r) in answers.items()]
    idle = all(d == 0 and not p for d, p, _ in answers.values()) and expected <= answers.keys()
    got = quiet_counts(statuses, expected)
    assert (got is not None) == idle
    if got is not None:
        assert got == {w: r for w, (_, _, r) in answers.items()}


def test_an_inbox_names_the_drops_its_stop_released() -> None:
    """Full inbox: a put held past ``block_s`` drops as before; one released by the stop event is counted apart."""
    inbox = Inbox(max_items=1, max_bytes=1 << 20, block_s=0.01)
    never, stopped = threading.Event(), threading.Event()
    stopped.set()
    assert inbox.put("a", 1, never)
    assert not inbox.put("b", 1, never)  # full for block_s
    assert inbox.take_dropped() == (1, 0)
    assert inbox.get(None) == "a"
    assert inbox.put("c", 1, stopped)  # room: the stop does not refuse what fits
    assert not inbox.put("d", 1, stopped)
    assert inbox.take_dropped() == (1, 1)
