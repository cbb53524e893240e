"""What the recorder's tests over real processes share: a recorder subprocess on a router and a client beside it."""

from __future__ import annotations

import json
import signal
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh
from conftest import REPO, fixstream_cmd, service_env, wait_until
from samples import available_examples

from schemas import Message
from shared import codec, keys
from shared.mcap_io import Record, decode_record, iter_records
from shared.session import open_session
from shared.settings import ZenohSettings


def examples() -> dict[str, Message]:
    """One example of every model that has one (completeness is the contract test's business)."""
    return available_examples()


def restamp(msg: Message, seq: int, source: str) -> Message:
    header = msg.header.model_copy(update={"seq": seq, "source": source, "stamp_ns": 1_000_000 + seq})
    return msg.model_copy(update={"header": header})


@dataclass
class Recorder:
    """A recorder subprocess and a Zenoh client session talking to it."""

    proc: subprocess.Popen[bytes]
    session: zenoh.Session
    instance: str
    out_dir: Path
    log_path: Path
    publishers: dict[str, zenoh.Publisher] = field(default_factory=dict)

    def status(self) -> dict[str, Any]:
        replies = list(self.session.get(keys.status("recorder", self.instance), timeout=2.0))
        for reply in replies:
            if reply.ok is not None:
                body: dict[str, Any] = json.loads(reply.ok.payload.to_bytes())
                return body
        return {}

    def alive(self) -> bool:
        replies = self.session.liveliness().get(keys.alive("recorder", self.instance), timeout=2.0)
        return any(r.ok is not None for r in replies)

    def publisher(self, key: str) -> zenoh.Publisher:
        """A reliable, blocking publisher that the recorder's subscriber already matches."""
        pub = self.publishers.get(key)
        if pub is None:
            pub = self.session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
            assert wait_until(lambda: pub.matching_status.matching, timeout=10), f"recorder does not match {key}"
            self.publishers[key] = pub
        return pub

    def send(self, key: str, msg: Message) -> None:
        self.publisher(key).put(codec.encode(msg), encoding=zenoh.Encoding(codec.encoding_of(type(msg))))

    def send_raw(self, key: str, payload: bytes, encoding: str) -> None:
        self.publisher(key).put(payload, encoding=zenoh.Encoding(encoding))

    def wait_status(self, predicate: Any, timeout: float = 20.0) -> dict[str, Any]:
        last: dict[str, Any] = {}

        def check() -> bool:
            nonlocal last
            last = self.status()
            return bool(last) and bool(predicate(last))

        assert wait_until(check, timeout=timeout, interval=0.1), f"status never matched; last: {last}\n{self.log()}"
        return last

    def terminate(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        rc = self.proc.wait(timeout=20)
        assert rc == 0, f"recorder exited {rc}\n{self.log()}"

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")[-4000:]


@contextmanager
def recorder(
    router: str, tmp_path: Path, instance: str = "t1", cli: list[str] | None = None, **env: str
) -> Iterator[Recorder]:
    """Start ``fixstream run recorder`` (or ``fixstream record <cli>``) and wait until it is alive."""
    out_dir = tmp_path / "out"
    log_path = tmp_path / f"recorder-{instance}.log"
    settings = {"FIXSTREAM_RECORDER_INSTANCE": instance, "FIXSTREAM_RECORDER_OUT_DIR": str(out_dir), **env}
    cmd = fixstream_cmd("record", *cli) if cli is not None else fixstream_cmd("run", "recorder")
    with log_path.open("wb") as log_file:
        proc = subprocess.Popen(cmd, cwd=REPO, env=service_env(router, **settings), stdout=log_file, stderr=log_file)
    session = open_session(ZenohSettings(mode="client", connect=[router]))
    rec = Recorder(proc=proc, session=session, instance=instance, out_dir=out_dir, log_path=log_path)
    try:
        assert wait_until(lambda: proc.poll() is not None or rec.alive(), timeout=30), rec.log()
        assert proc.poll() is None, f"recorder died at start\n{rec.log()}"
        yield rec
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        for pub in rec.publishers.values():
            pub.undeclare()
        session.close()


def records_of(paths: list[Path]) -> list[Record]:
    return [r for p in paths for r in iter_records(p)]


def by_topic(records: list[Record]) -> dict[str, list[Message]]:
    out: dict[str, list[Message]] = {}
    for r in records:
        out.setdefault(r.topic, []).append(decode_record(r))
    return out
