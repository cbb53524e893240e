"""Start the planned processes in order, show their output and readiness, and stop them cleanly.

* Start order is the plan's (topological from depends_on). A service starts once each dependency is
  ready: the embedded router when its port accepts, a ``fixstream run`` service when its liveliness
  token is seen, ``service_completed_successfully`` dependencies when they exited 0, others once started.
* The driver (label ``fixstream.role: driver``) ending, any service failing, or SIGINT/SIGTERM to the
  runner stops the stack: each running process gets its stop signal (SIGTERM) in reverse start order
  and up to its timeout before SIGKILL. A second signal kills the rest at once.
* The exit code is the driver's if it failed, 1 if another service failed (non-zero exit, killed after
  the timeout, never ready; a recorder exits 1 when a write failed) or a recorder wrote no MCAP file,
  128+signal after an interrupt, else 0. A stopped service must exit 0 or die
  by the stop signal; a stopped driver (interrupted before its end) may exit with any code.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

from .console import Console
from .plan import ProcessSpec, StackPlan
from .readiness import LivelinessWatch, port_open

#: seconds between the two status rounds that must agree for the stack to count as settled (``_settle``)
SETTLE_INTERVAL_S = 0.25


@dataclass
class Proc:
    spec: ProcessSpec
    popen: subprocess.Popen[str] | None = None
    reader: threading.Thread | None = None
    ready: bool = False
    returncode: int | None = None
    stop_sent: bool = False
    killed: bool = False


@dataclass
class StackResult:
    exit_code: int
    returncodes: dict[str, int | None]
    failures: list[str] = field(default_factory=list)
    recordings: list[Path] = field(default_factory=list)
    start_order: list[str] = field(default_factory=list)
    #: recorder services that ran (their files are the recordings)
    recorders: list[str] = field(default_factory=list)


def describe_exit(rc: int) -> str:
    if rc < 0:
        try:
            return f"killed by {signal.Signals(-rc).name}"
        except ValueError:
            return f"killed by signal {-rc}"
    return f"exited with code {rc}"


class Supervisor:
    def __init__(
        self,
        plan: StackPlan,
        console: Console | None = None,
        ready_timeout: float = 60.0,
        drain: float = 30.0,
        poll: float = 0.05,
    ) -> None:
        self.plan = plan
        self.console = console or Console()
        self.ready_timeout = ready_timeout
        self.drain = drain
        self.poll = poll
        self.procs = {p.service: Proc(p) for p in plan.processes}
        self.started: list[Proc] = []
        self.failures: list[str] = []
        self.signals: list[int] = []
        self.watch: LivelinessWatch | None = None
        self._watch_failed = False
        for name in self.procs:
            self.console.register(name)

    # ----- public ---------------------------------------------------------------------------------
    def request_stop(self, signum: int = signal.SIGTERM) -> None:
        """Stop the stack (what SIGINT/SIGTERM to the runner do); a second request kills."""
        self.signals.append(signum)

    def run(self) -> StackResult:
        t0 = time.time()
        previous = self._install_signal_handlers()
        try:
            driver = self._main_loop()
            self._shutdown(drain=driver is not None and driver.returncode == 0 and not self.failures)
        finally:
            self._restore_signal_handlers(previous)
            if self.watch is not None:
                self.watch.close()
            for p in self.started:
                if p.reader is not None:
                    p.reader.join(timeout=2.0)
            recordings = self._recordings(t0)
            for d in self.plan.temp_dirs:
                shutil.rmtree(d, ignore_errors=True)
        recorders = [p.spec.service for p in self.started if p.spec.files_list is not None]
        if recorders and not recordings and not self.signals:
            # a recording is never silently empty with exit code 0 (docs/stack.md)
            self.failures.append(f"{', '.join(recorders)}: no MCAP file written")
            self.console.event(self.failures[-1])
        return StackResult(
            exit_code=self._exit_code(),
            returncodes={name: p.returncode for name, p in self.procs.items()},
            failures=list(self.failures),
            recordings=recordings,
            start_order=[p.spec.service for p in self.started],
            recorders=recorders,
        )

    # ----- main loop ------------------------------------------------------------------------------
    def _main_loop(self) -> Proc | None:
        pending = list(self.plan.processes)
        drivers = [self.procs[p.service] for p in self.plan.processes if p.driver]
        driver = drivers[0] if drivers else None
        waiting_since = time.monotonic()
        while True:
            self._reap()
            self._probe()
            if self.signals or self.failures:
                return driver
            if driver is not None and driver.returncode is not None:
                return driver
            if not pending and all(p.returncode is not None for p in self.started):
                return driver
            if pending:
                status = self._dependencies(pending[0])
                if status == "ok":
                    self._start(self.procs[pending.pop(0).service])
                    waiting_since = time.monotonic()
                    continue
                if status != "wait":
                    self.failures.append(status)
                    return driver
                if time.monotonic() - waiting_since > self.ready_timeout:
                    waits = [d for d in pending[0].depends_on if not self.procs[d].ready]
                    self.failures.append(
                        f"{pending[0].service}: dependencies not ready after {self.ready_timeout:g} s: "
                        + ", ".join(f"{d} ({self._probe_name(self.procs[d])})" for d in waits)
                    )
                    self.console.event(self.failures[-1])
                    return driver
            time.sleep(self.poll)

    def _probe_name(self, p: Proc) -> str:
        if p.spec.router_port is not None:
            return f"port {p.spec.router_port}"
        return f"liveliness {p.spec.ready_key}" if p.spec.ready_key else "start"

    def _dependencies(self, spec: ProcessSpec) -> str:
        for dep, condition in spec.depends_on.items():
            p = self.procs.get(dep)
            if p is None:
                continue
            if condition == "service_completed_successfully":
                if p.returncode is None:
                    return "wait"
                if p.returncode != 0:
                    return f"{spec.service}: dependency {dep} did not complete successfully ({p.returncode})"
            elif not p.ready and p.returncode is None:
                return "wait"
        return "ok"

    def _start(self, p: Proc) -> None:
        spec = p.spec
        try:
            p.popen = subprocess.Popen(
                spec.argv,
                env=spec.env,
                cwd=spec.cwd,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                errors="replace",
                bufsize=1,
                start_new_session=True,  # Ctrl-C reaches the runner only; it stops services in order
            )
        except OSError as exc:
            p.returncode = 127
            self.failures.append(f"{spec.service}: cannot start {spec.argv[0]!r}: {exc}")
            self.console.event(self.failures[-1])
            return
        self.started.append(p)
        p.reader = threading.Thread(target=self._pump, args=(p,), name=f"up-{spec.service}", daemon=True)
        p.reader.start()
        role = " (driver)" if spec.driver else ""
        self.console.event(f"{spec.service} started{role}, pid {p.popen.pid}")
        if spec.router_port is None and (spec.ready_key is None or self._watch_failed or not self.plan.endpoint):
            p.ready = True

    def _pump(self, p: Proc) -> None:
        assert p.popen is not None and p.popen.stdout is not None
        for line in p.popen.stdout:
            self.console.line(p.spec.service, line.rstrip("\r\n"))

    def _reap(self) -> None:
        for p in self.started:
            if p.returncode is not None or p.popen is None:
                continue
            rc = p.popen.poll()
            if rc is None:
                continue
            p.returncode = rc
            self.console.event(f"{p.spec.service} {describe_exit(rc)}")
            if p.stop_sent:
                # stopped: a clean exit or death by the stop signal; the driver may report its interruption
                clean = (0, -p.spec.stop_signal, 128 + p.spec.stop_signal)
                if not p.killed and not p.spec.driver and rc not in clean:
                    self.failures.append(f"{p.spec.service}: {describe_exit(rc)} when stopped")
            elif rc != 0:
                self.failures.append(f"{p.spec.service}: {describe_exit(rc)}")

    def _probe(self) -> None:
        for p in self.started:
            if p.ready or p.returncode is not None:
                continue
            spec = p.spec
            if spec.router_port is not None:
                if port_open(spec.router_port):
                    p.ready = True
                    self.console.event(f"{spec.service} ready: embedded router on {self.plan.endpoint}")
                    self._open_watch(spec)
            elif spec.ready_key and self.watch is not None:
                key = self.watch.match(spec.ready_key)
                if key:
                    p.ready = True
                    self.console.event(f"{spec.service} ready: {key}")

    def _open_watch(self, spec: ProcessSpec) -> None:
        if (
            self.watch is not None
            or self.plan.endpoint is None
            or not self.plan.endpoint.endswith(f":{spec.router_port}")
        ):
            return
        watch = LivelinessWatch(self.plan.endpoint, tls=self.plan.client_tls)
        try:
            watch.open()
        except Exception as exc:  # readiness is a convenience; the stack still runs without it
            self._watch_failed = True
            self.console.event(f"cannot watch liveliness ({exc}); services count as ready once started")
            for p in self.started:
                p.ready = p.ready or p.spec.router_port is None
            return
        self.watch = watch

    # ----- shutdown -------------------------------------------------------------------------------
    def _shutdown(self, drain: bool) -> None:
        running = [p for p in self.started if p.returncode is None]
        if not running:
            return
        if self.signals:
            self.console.event(f"{signal.Signals(self.signals[0]).name} received, stopping the stack")
        elif self.failures:
            self.console.event("a service failed, stopping the stack")
        else:
            self.console.event("stopping the stack")
        if drain and self.drain > 0:
            self._settle(self.drain)
        for p in reversed(self.started):
            self._reap()
            if p.returncode is not None or p.popen is None:
                continue
            if p.spec.router_port is not None and self.watch is not None:
                self.watch.close()
                self.watch = None
            self._stop_one(p)
        self._reap()

    def _stop_one(self, p: Proc) -> None:
        assert p.popen is not None
        sig = signal.SIGKILL if len(self.signals) > 1 else p.spec.stop_signal
        self.console.event(f"stopping {p.spec.service} ({signal.Signals(sig).name})")
        p.stop_sent = True
        p.killed = sig == signal.SIGKILL
        self._signal(p, sig)
        deadline = time.monotonic() + p.spec.stop_timeout
        while p.popen.poll() is None:
            if not p.killed and len(self.signals) > 1:
                self.console.event(f"{p.spec.service}: interrupted again, SIGKILL")
            elif not p.killed and time.monotonic() > deadline:
                self.failures.append(f"{p.spec.service}: did not stop within {p.spec.stop_timeout:g} s, SIGKILL")
                self.console.event(self.failures[-1])
            else:
                time.sleep(self.poll)
                continue
            p.killed = True
            self._signal(p, signal.SIGKILL)
        self._reap()

    @staticmethod
    def _signal(p: Proc, sig: int) -> None:
        assert p.popen is not None
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(p.popen.pid, sig)

    def _settle(self, max_s: float) -> None:
        """Wait, at most ``max_s``, until the stack has settled after the driver's end: every running ``fixstream
        run`` service (and any other that answered before) answers its status query with an empty inbox and no
        run end pending, and no service received anything between two such answers :data:`SETTLE_INTERVAL_S`
        apart. A fixed wait instead stopped a recorder still behind the player (under load: thousands of samples
        held back in Zenoh and dropped at the stop). Without a liveliness watch (no router of ours) it waits
        ``min(max_s, 1)`` s."""
        if self.watch is None:
            self._sleep(min(max_s, 1.0))
            return
        end = time.monotonic() + max_s
        previous: dict[str, int] | None = None
        while not self.signals and time.monotonic() < end:
            own = {p.spec.ready_key for p in self.started if p.spec.answers_status and p.returncode is None}
            expected = {who for k in own if k and (who := self.watch.alive_key(k))}
            counts = self.watch.quiet_counts(min(0.5, max(0.1, end - time.monotonic())), expected)
            if counts is not None and counts == previous:
                return
            previous = counts
            self._sleep(min(SETTLE_INTERVAL_S, max(0.0, end - time.monotonic())))
        if not self.signals:
            self.console.event(f"the stack had not settled {max_s:g} s after the driver's end; stopping it anyway")

    def _sleep(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not self.signals:
            self._reap()
            time.sleep(self.poll)

    # ----- results --------------------------------------------------------------------------------
    def _exit_code(self) -> int:
        driver = next((p for p in self.procs.values() if p.spec.driver), None)
        if driver is not None and driver.returncode not in (None, 0) and not driver.stop_sent:
            rc = driver.returncode
            return rc if rc is not None and rc > 0 else 1
        if self.failures:
            return 1
        if self.signals:
            return 128 + self.signals[0]
        return 0

    def _recordings(self, since: float) -> list[Path]:
        """The run's MCAP files: those its recorders listed (every recorder that ran lists its own, see
        ProcessSpec.files_list), else the new ones in the writable mounts."""
        lists = [p.spec.files_list for p in self.started if p.spec.files_list is not None]
        if lists:
            listed: list[Path] = []
            for path in lists:
                with contextlib.suppress(OSError):
                    listed += [Path(line) for line in path.read_text().splitlines() if line.strip()]
            return [f for f in dict.fromkeys(listed) if f.is_file()]
        found: list[Path] = []
        for d in self.plan.output_dirs:
            if d.is_dir():
                found += [f for f in sorted(d.rglob("*.mcap")) if f.stat().st_mtime >= since - 1.0]
        return found

    # ----- signals --------------------------------------------------------------------------------
    def _install_signal_handlers(self) -> dict[int, Any]:
        if threading.current_thread() is not threading.main_thread():
            return {}

        def handler(signum: int, _frame: FrameType | None) -> None:
            self.request_stop(signum)

        previous: dict[int, Any] = {}
        # SIGHUP too: a closed terminal or a dropped ssh session hangs up `up` alone (its services run in sessions of
        # their own), which once left the whole stack running, orphaned, and its recording never finalised
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            previous[sig] = signal.signal(sig, handler)
        return previous

    @staticmethod
    def _restore_signal_handlers(previous: dict[int, Any]) -> None:
        for sig, old in previous.items():
            signal.signal(sig, old)
