"""Helpers of the command-line client tests: a test publisher on a real router, and client processes."""

from __future__ import annotations

import subprocess
import time
from collections.abc import Sequence

import zenoh
from conftest import REPO, fixstream_cmd, wait_until

from schemas import Depth, Header, Message, Truth
from shared import codec
from shared.session import open_session
from shared.settings import ZenohSettings

SOURCE = "test/pub"


def truth(seq: int, stamp_ns: int, platform: str = "p1") -> Truth:
    return Truth(
        header=Header(stamp_ns=stamp_ns, frame_id="local_enu", source=SOURCE, seq=seq),
        platform=platform,
        position_m=[float(seq), 2.0 * seq, -3.0],
    )


def depth(seq: int, stamp_ns: int) -> Depth:
    return Depth(header=Header(stamp_ns=stamp_ns, frame_id="local_enu", source=SOURCE, seq=seq), depth_m=10.0 + seq)


class TestPublisher:
    """A client session on the router that puts messages with their fixstream encoding."""

    __test__ = False  # not a test class

    def __init__(self, router: str) -> None:
        self.session = open_session(ZenohSettings(mode="client", connect=[router]))

    def wait_for_subscriber(self, key: str, timeout: float = 20.0) -> None:
        """Block until a subscriber elsewhere matches ``key`` (the client under test is listening)."""
        probe = self.session.declare_publisher(key)
        try:
            assert wait_until(lambda: probe.matching_status.matching, timeout=timeout), f"no subscriber on {key}"
        finally:
            probe.undeclare()

    def put(self, key: str, msg: Message) -> None:
        self.session.put(key, codec.encode(msg), encoding=zenoh.Encoding(codec.encoding_of(type(msg))))

    def put_raw(self, key: str, payload: bytes, encoding: str) -> None:
        self.session.put(key, payload, encoding=zenoh.Encoding(encoding))

    def paced(self, items: Sequence[tuple[float, str, Message]]) -> None:
        """Put ``(t_s, key, msg)`` items at t_s after now, against absolute deadlines (a late put does not delay
        the next ones, so the mean rate over many periods is the nominal one)."""
        t0 = time.monotonic()
        for t_s, key, msg in items:
            delay = t0 + t_s - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            self.put(key, msg)

    def close(self) -> None:
        self.session.close()


def start(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(fixstream_cmd(*args), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def finish(proc: subprocess.Popen[str], timeout: float = 60.0) -> tuple[int, str, str]:
    out, err = proc.communicate(timeout=timeout)
    return proc.returncode, out, err
