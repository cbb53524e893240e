"""The service base's cost per message, against a bare Zenoh callback in the same run (issue 18, item 2).

Real processes on one router (``fixstream router``): a publisher process puts ``BENCH_SERVICE_BASE_N`` msgpack
``Depth`` messages (82 bytes, its own ``header.source`` and ``seq``) as fast as a blocking publisher may; one
consumer process at a time takes them, and the benchmark process counts what the consumer republishes. Consumers:

* ``bare callback`` (the anchor): one Python callback per sample that counts (the transport's cost into Python);
* ``bare callback on a wildcard``: the same subscribing with the service's key expression (``.../depth/*``): what
  Zenoh charges for a wildcard subscription whose keys are not declared (the base declares them: see
  :meth:`~shared.service.Service._declare_wire_key`);
* ``bare relay``: the callback counts and puts the payload back on an output key (the transport's cost both ways);
* ``service base``: a :class:`~shared.service.Service` whose typed subscription takes ``Depth`` and whose core does
  nothing: its handler returns the message as its output. Every message goes receive -> Zenoh's FIFO -> the
  subscription's delivery thread -> inbox -> unpack -> seq and stamp checks -> validate -> dispatch -> stamp
  source/seq -> encode -> put, as in every fixstream service;
* variants of its receiving end (not shipped): a Python callback per sample into the inbox (what the base did before
  its delivery threads, :class:`CallbackEchoService`), that callback on Zenoh's network thread
  (:class:`DirectEchoService`), processing in the callback (:class:`InlineEchoService`), and pulling from the FIFO
  in the service's own thread with no inbox (:class:`FifoEchoService`, :class:`FifoDrainEchoService`);
* ``service+<variant>``: the service base with a Zenoh transport setting (:data:`TRANSPORT_VARIANTS`) or an
  environment variable (:data:`ENV_VARIANTS`) of its own process.

Each consumer measures its own CPU time (``time.process_time``: every thread of the process, Zenoh's included) and
wall time from its ``WARM``-th message to its last; CPU per message is the figure (the machine is shared, wall time
is not). The in-process rows time the base's path in one thread (the callback's enqueue and the loop's take;
``process`` with a put that does nothing) and the steps in it no service can skip (unpack, validate, encode), so the
table says how much of the cost is the wire format, how much the base around it and how much the hand-over between
Zenoh's thread and the service's.

``python -m bench service_base`` (or ``make bench``).
"""

from __future__ import annotations

import atexit
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
import timeit
from collections.abc import Iterable
from pathlib import Path
from typing import Any, ClassVar, cast

import msgpack
import zenoh

from schemas import Depth, Header, Message
from shared import codec
from shared.service import Output, Service, Subscription
from shared.session import open_session
from shared.settings import ServiceSettings, ZenohSettings

from .procstat import THREAD_GROUPS, thread_cpu
from .report import emit
from .stack import REPO, router

N = int(os.environ.get("BENCH_SERVICE_BASE_N", "200000"))
#: messages before the measured span (imports, first allocations, the publisher's start)
WARM = int(os.environ.get("BENCH_SERVICE_BASE_WARM", "20000"))
IN_KEY = "fixstream/sensor/bench/depth/d0"
OUT_KEY = "fixstream/fix/bench/echo"
ENCODING = codec.encoding_of(Depth)


class EchoService(Service):
    """A service whose core does nothing: every Depth it takes is its output."""

    name: ClassVar[str] = "bench_echo"

    def __init__(self, settings: ServiceSettings, zenoh_settings: ZenohSettings | None = None) -> None:
        super().__init__(settings, zenoh_settings)
        self.n = 0
        self.t0: tuple[float, float] | None = None
        self.t1: tuple[float, float] | None = None
        self.threads0: dict[str, float] = {}
        self.threads1: dict[str, float] = {}
        #: the deepest the inbox was, sampled every 1,000 messages over the measured span
        self.max_depth = 0

    def subscriptions(self) -> list[Subscription]:
        return [Subscription("fixstream/sensor/bench/depth/*", self.on_depth, accepts=(Depth,))]

    def on_depth(self, key: str, msg: Message) -> Iterable[Output]:
        self.n += 1
        if self.n % 1000 == 0 and self.n > WARM:
            self.max_depth = max(self.max_depth, self._queue.qsize())
        if self.n == WARM:
            self.threads0 = thread_cpu()
            self.t0 = (time.process_time(), time.perf_counter())
        elif self.n == N:
            self.t1 = (time.process_time(), time.perf_counter())
            self.threads1 = thread_cpu()
            self.stop()
        return (Output(OUT_KEY, msg),)


class InlineEchoService(EchoService):
    """The same service processing each sample in Zenoh's callback thread (no inbox, no second thread): what the
    hand-over between the two threads costs, measured as a variant. Not what services run: a core that stalls holds
    Zenoh's delivery thread, and the session with it (the inbox's reason, ``tests/test_faults.py``)."""

    def _declare(self) -> None:
        assert self.session is not None
        self._subs = self.subscriptions()
        wire_keys, process = self._wire_keys, self.process

        def on_sample(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            if key not in wire_keys:
                self._declare_wire_key(key)
            process(key, sample.payload.to_bytes(), str(sample.encoding), time.time_ns())

        self._declared.append(self.session.declare_subscriber(self._subs[0].key_expr, on_sample))

    def _loop(self) -> None:
        self._stop.wait()


class FifoEchoService(EchoService):
    """The same service receiving through Zenoh's ``FifoChannel`` (the processing thread pulls samples; no Python
    callback on Zenoh's thread, no inbox): the batching the issue suggests, measured as a variant. Not what services
    run: the FIFO is bounded in items only and, full, holds Zenoh's thread for as long as the service is busy (the
    inbox bounds bytes too, and drops and counts after ``enqueue_block_s``)."""

    def _declare(self) -> None:
        assert self.session is not None
        self._subs = self.subscriptions()
        self._fifo = self.session.declare_subscriber(self._subs[0].key_expr, zenoh.handlers.FifoChannel(256))

    def _loop(self) -> None:
        fifo, process, wire_keys = self._fifo, self.process, self._wire_keys
        while not self._stop.is_set():
            s = fifo.recv()
            key = str(s.key_expr)
            if key not in wire_keys:
                self._declare_wire_key(key)
            process(key, s.payload.to_bytes(), str(s.encoding), time.time_ns())

    def _shutdown(self) -> None:
        assert self.session is not None
        self._fifo.undeclare()
        for pub in self._publishers.values():
            pub.undeclare()
        self.session.close()


class DirectEchoService(EchoService):
    """:class:`CallbackEchoService` with its callback run on Zenoh's network thread (``Callback(indirect=False)``):
    no Python thread between Zenoh and the inbox, but Zenoh's thread takes the GIL for every sample (a variant)."""

    def _declare(self) -> None:
        assert self.session is not None
        self._subs = self.subscriptions()
        cb = zenoh.handlers.Callback(self._enqueue, indirect=False)
        self._declared.append(self.session.declare_subscriber(self._subs[0].key_expr, cb))


class FifoDrainEchoService(FifoEchoService):
    """:class:`FifoEchoService` taking what has queued with ``try_recv`` (no GIL release per sample) and blocking in
    ``recv`` only when the FIFO is empty (a variant)."""

    def _loop(self) -> None:
        fifo, process, wire_keys = self._fifo, self.process, self._wire_keys
        try_recv, time_ns = fifo.try_recv, time.time_ns
        while not self._stop.is_set():
            s = fifo.recv()
            while s is not None:
                key = str(s.key_expr)
                if key not in wire_keys:
                    self._declare_wire_key(key)
                process(key, s.payload.to_bytes(), str(s.encoding), time_ns())
                if self._stop.is_set():
                    return
                s = try_recv()


class CallbackEchoService(EchoService):
    """The same service receiving through a Python callback per sample on the thread Zenoh runs it on (its
    "indirect" thread), which puts into the inbox: what the base shipped before the delivery threads (a variant)."""

    def _declare(self) -> None:
        assert self.session is not None
        self._subs = self.subscriptions()
        self._declared.append(self.session.declare_subscriber(self._subs[0].key_expr, self._enqueue))


class _NullPublisher:
    def put(self, payload: bytes, encoding: Any = None) -> None:
        pass


class _NullSession:
    """Stands in for the session in the in-process rows: its publishers put nowhere."""

    def declare_publisher(self, key: str, **kwargs: Any) -> _NullPublisher:
        return _NullPublisher()

    def declare_keyexpr(self, key: str) -> None:
        return None


def _payload(seq: int) -> bytes:
    return codec.encode(Depth(header=Header(stamp_ns=seq * 1_000_000, source="bench/p0", seq=seq), depth_m=35.5))


# ----- the consumer processes --------------------------------------------------------------------------------------
#: Zenoh configuration variants of the consumer's session (``<kind>+<variant>``): JSON5 paths and values
TRANSPORT_VARIANTS: dict[str, dict[str, Any]] = {
    "qos_off": {"transport/unicast/qos/enabled": False},
    "batch_5ms": {"transport/link/tx/queue/batching/time_limit": 5},
    "rxbuf_1m": {"transport/link/rx/buffer_size": 1 << 20},
    "queue_16": {"transport/link/tx/queue/size/data": 16},
    "lowlat": {"transport/unicast/qos/enabled": False, "transport/unicast/lowlatency": True},
}
#: environment variants of the consumer process (``<kind>+<variant>``): Zenoh's runtime threads, the inbox's bound
ENV_VARIANTS: dict[str, dict[str, str]] = {
    "rx1": {"ZENOH_RUNTIME": "(rx: (worker_threads: 1))"},
    "q10k": {"FIXSTREAM_QUEUE_SIZE": "10000"},
}


def _consumer_settings(variant: str, endpoint: str) -> ZenohSettings:
    """The consumer's Zenoh settings for a transport variant (its config written to a temporary JSON5 file)."""
    zs = ZenohSettings(mode="client", connect=[endpoint])
    if variant in TRANSPORT_VARIANTS:
        cfg: dict[str, Any] = {}
        for path, value in TRANSPORT_VARIANTS[variant].items():
            *parents, leaf = path.split("/")
            node = cfg
            for p in parents:
                node = node.setdefault(p, {})
            node[leaf] = value
        fd, name = tempfile.mkstemp(suffix=".json5")
        with os.fdopen(fd, "w") as f:
            json.dump(cfg, f)
        atexit.register(os.unlink, name)  # read when the session opens; gone with the consumer process
        zs = ZenohSettings(mode="client", connect=[endpoint], config_file=Path(name))
    return zs


def serve(kind: str, endpoint: str) -> None:
    """A consumer process: ``bare``, ``relay`` or ``service`` (``+variant``: a transport variant); prints ``ready``,
    then ``cpu_s wall_s`` of the measured span."""
    kind, _, variant = kind.partition("+")
    zs = _consumer_settings(variant, endpoint)
    key_expr = "fixstream/sensor/bench/depth/*" if kind == "bare_wildcard" else IN_KEY
    if kind in SERVICES:
        svc = SERVICES[kind](ServiceSettings(instance="b0"), zs)
        threading.Timer(1.0, lambda: print("ready", flush=True)).start()  # run() declares within the first second
        svc.run()
        assert svc.t0 is not None and svc.t1 is not None
        threads = {g: svc.threads1[g] - svc.threads0[g] for g in svc.threads0} | {"max_depth": svc.max_depth}
        print(f"{svc.t1[0] - svc.t0[0]} {svc.t1[1] - svc.t0[1]} {json.dumps(threads)}", flush=True)
        return
    session = open_session(zs)
    pub = session.declare_publisher(OUT_KEY, congestion_control=zenoh.CongestionControl.BLOCK)
    enc = zenoh.Encoding(ENCODING)
    done = threading.Event()
    state: dict[str, Any] = {"n": 0}
    relay = kind == "relay"

    def on_sample(sample: zenoh.Sample) -> None:
        n = state["n"] = state["n"] + 1
        if relay:
            pub.put(sample.payload.to_bytes(), encoding=enc)
        if n == WARM:
            state["t0"] = (time.process_time(), time.perf_counter())
        elif n == N:
            state["t1"] = (time.process_time(), time.perf_counter())
            done.set()

    sub = session.declare_subscriber(key_expr, on_sample)
    print("ready", flush=True)
    done.wait()
    (c0, w0), (c1, w1) = state["t0"], state["t1"]
    print(f"{c1 - c0} {w1 - w0}", flush=True)
    sub.undeclare()
    session.close()


SERVICES: dict[str, type[EchoService]] = {
    "service": EchoService,
    "service_inline": InlineEchoService,
    "service_fifo": FifoEchoService,
    "service_direct": DirectEchoService,
    "service_fifo_drain": FifoDrainEchoService,
    "service_callback": CallbackEchoService,
}


def publish(endpoint: str) -> None:
    """The publisher process: N Depth messages, blocking, as fast as the consumer takes them."""
    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    pub = session.declare_publisher(IN_KEY, congestion_control=zenoh.CongestionControl.BLOCK)
    enc = zenoh.Encoding(ENCODING)
    msg = msgpack.unpackb(_payload(0))
    header = msg["header"]
    print("ready", flush=True)
    sys.stdin.readline()
    for seq in range(N):
        header["seq"], header["stamp_ns"] = seq, seq * 1_000_000
        pub.put(msgpack.packb(msg), encoding=enc)
    print("done", flush=True)
    sys.stdin.readline()
    session.close()


def _spawn(fn: str, *args: str, env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    code = f"import sys; from bench.bench_service_base import {fn}; {fn}(*sys.argv[1:])"
    return subprocess.Popen(
        [sys.executable, "-c", code, *args],
        cwd=REPO,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "FIXSTREAM_LOG_LEVEL": "WARNING", **(env or {})},
    )


def run_consumer(kind: str, endpoint: str) -> dict[str, Any]:
    """One consumer against the publisher; its CPU and wall time per message over the measured span, and what the
    benchmark process received of its outputs."""
    got = [0]
    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    counter = session.declare_subscriber(OUT_KEY, lambda s: got.__setitem__(0, got[0] + 1))
    variant = kind.partition("+")[2]
    consumer = _spawn("serve", kind, endpoint, env=ENV_VARIANTS.get(variant, {}))
    publisher = _spawn("publish", endpoint)
    try:
        assert consumer.stdout is not None and publisher.stdout is not None and publisher.stdin is not None
        assert consumer.stdout.readline().strip() == "ready"
        assert publisher.stdout.readline().strip() == "ready"
        time.sleep(0.5)  # both declared and known to the router
        publisher.stdin.write("\n")
        publisher.stdin.flush()
        line = consumer.stdout.readline().split(maxsplit=2)
        cpu_s, wall_s = float(line[0]), float(line[1])
        threads: dict[str, float] = json.loads(line[2]) if len(line) > 2 else {}
        publisher.stdin.write("\n")
        publisher.stdin.flush()
        publisher.wait(timeout=30)
        consumer.wait(timeout=30)
        deadline = time.monotonic() + 5
        while not kind.startswith("bare") and got[0] < N and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        for p in (consumer, publisher):
            if p.poll() is None:
                p.kill()
        counter.undeclare()
        session.close()
    span = N - WARM
    max_depth = int(threads.pop("max_depth", 0))
    return {
        "cpu_us_per_msg": cpu_s / span * 1e6,
        "msg_per_s": span / wall_s,
        "outputs_received": got[0] if not kind.startswith("bare") else 0,
        "threads_us_per_msg": {g: t / span * 1e6 for g, t in threads.items()},
        "max_inbox_depth": max_depth,
    }


# ----- in-process: where the microseconds go -------------------------------------------------------------------------
def in_process(endpoint: str) -> dict[str, float]:
    """µs of CPU per message of the base's path in this process (best of 5 repeats): the callback's enqueue and the
    loop's take of real Zenoh samples, ``process`` of the no-op service with a put that does nothing, and the steps
    in it that no service can skip."""
    payload = _payload(7)
    obj = codec.unpack(payload)
    msg = codec.validate(Depth, obj)
    reps = 20_000

    def best(fn: Any, number: int = reps) -> float:
        return min(timeit.repeat(fn, number=number, repeat=5, timer=time.process_time)) / number * 1e6

    seq = iter(range(10**9))
    svc = EchoService(ServiceSettings(instance="b0"))
    svc._subs = svc.subscriptions()
    svc.session = cast(zenoh.Session, _NullSession())
    payloads = [_payload(i) for i in range(6 * reps)]
    it = iter(payloads)

    # real samples: one put through the router, delivered back to this process
    got: list[zenoh.Sample] = []
    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    sub = session.declare_subscriber(IN_KEY, got.append)
    session.put(IN_KEY, payload, encoding=zenoh.Encoding(ENCODING))
    deadline = time.monotonic() + 5
    while not got and time.monotonic() < deadline:
        time.sleep(0.01)
    sub.undeclare()
    session.close()
    sample = got[0]
    enqueue, take = svc._enqueue, svc._queue.get

    def handover() -> None:
        for _ in range(1000):
            enqueue(sample)
        for _ in range(1000):
            take()

    return {
        "enqueue_and_take": best(handover, 20) / 1000,
        "process": best(lambda: svc.process(IN_KEY, next(it), ENCODING, 0)),
        "unpack": best(lambda: codec.unpack(payload)),
        "validate": best(lambda: codec.validate(Depth, obj)),
        "encode_stamped": best(lambda: codec.encode_stamped(msg, "bench_echo/b0", next(seq))),
    }


LABELS = {
    "bare": "bare Zenoh callback that counts (anchor)",
    "bare_wildcard": "the same subscribing with a wildcard (keys not declared)",
    "relay": "bare callback that counts and puts the payload",
    "service": "service base, no-op core (shipped: FIFO -> delivery thread -> inbox -> own thread)",
    "service_callback": "the same with a Python callback per sample into the inbox (before)",
    "service_direct": "the same with that callback on Zenoh's network thread (variant)",
    "service_inline": "the same processing in Zenoh's callback thread, no inbox (variant)",
    "service_fifo": "the same pulling from the FIFO with recv, no inbox (variant)",
    "service_fifo_drain": "the same pulling with try_recv, recv when empty, no inbox (variant)",
}
KINDS = (
    *LABELS,
    *(f"service+{v}" for v in TRANSPORT_VARIANTS),
    *(f"service+{v}" for v in ENV_VARIANTS),
)


def _label(kind: str) -> str:
    base, _, variant = kind.partition("+")
    if not variant:
        return LABELS[base]
    what = TRANSPORT_VARIANTS.get(variant) or ENV_VARIANTS[variant]
    return "service base with " + ", ".join(f"{k.removeprefix('transport/')}={v}" for k, v in what.items())


def main() -> None:
    rows: list[list[Any]] = []
    figures: dict[str, Any] = {"n": N, "warm": WARM}
    with router() as endpoint:
        results = {k: run_consumer(k, endpoint) for k in KINDS}
        steps = in_process(endpoint)
    anchor = results["bare"]["cpu_us_per_msg"]
    for kind, r in results.items():
        cpu, threads = r["cpu_us_per_msg"], r["threads_us_per_msg"]
        split = [f"{threads[g]:.2f}" if g in threads else "" for g in THREAD_GROUPS]
        rate = f"{r['msg_per_s']:,.0f}"
        rows.append([_label(kind), f"{cpu:.2f}", f"{cpu / anchor:.2f}", f"{cpu - anchor:.2f}", *split, rate])
        figures[kind] = r
    figures["in_process_us"] = steps
    for step, us in steps.items():
        rows.append([f"in process: {step}", f"{us:.2f}", "", "", "", "", "", ""])
    emit(
        "service_base",
        [
            "path",
            "CPU µs/msg",
            "ratio to anchor",
            "over anchor µs",
            "own thread",
            "delivery / callback thread",
            "Zenoh network threads",
            "msg/s (wall)",
        ],
        rows,
        figures,
    )


if __name__ == "__main__":
    main()
