"""``fixstream foxglove``: the live bridge over a real Zenoh router (issue 8).

A ``fixstream foxglove`` process (``--port 0``, a scenario with a geodetic origin) bridges a real router; a
WebSocket client speaking the Foxglove protocol (the ``websockets`` package, subprotocol ``foxglove.sdk.v1``)
connects, waits for the channels to be advertised, subscribes to the raw channel of a key and to its scene and
map channels, while this test publishes ``Truth`` and ``Fix`` messages on Zenoh. The client receives them: the
raw channel carries the message's JSON (equal to what was published), the scene channel a
``foxglove.SceneUpdate`` decoded with the advertised schema, whose entity sits at the published position with
the published covariance as its 3σ ellipsoid, the map channel a ``foxglove.LocationFix`` at the right place.
SIGTERM stops the bridge cleanly (exit 0, a summary of what it served).

Issue 17, item 8: a client speaking only ``foxglove.websocket.v1`` (Lichtblick, older Foxglove) lists the channels
and receives messages; a browser page's foreign ``Origin`` is refused with HTTP 403, an allowed one and a client
with no ``Origin`` are served; the bridge listens on loopback only by default; and its topics are the recording's:
a recorder (with its Foxglove channels) and the bridge on the same stream, RadarPlot and RadarSite included, end
with the same set of topics.
"""

from __future__ import annotations

import asyncio
import base64
import json
import struct
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
import zenoh
from conftest import REPO, fixstream_cmd
from test_foxglove import GEODESY_ATOL_M, cov_of_sphere, proto_class
from test_recorded_track import enu_independent

from schemas import Fix, Header, Truth
from shared import codec, keys
from shared.estimates import POSITION, gaussian
from shared.foxglove.convert import Origin
from shared.session import open_session
from shared.settings import ZenohSettings

pytestmark = pytest.mark.e2e

ORIGIN = {"lat_deg": -33.9, "lon_deg": 151.2, "alt_m": 3.0}
TRUTH_KEY = keys.truth("auv9")
FIX_KEY = keys.fix("test", "auv9")
COV = [[25.0, 6.0, 0.0], [6.0, 9.0, 1.0], [0.0, 1.0, 4.0]]


def truth(i: int) -> Truth:
    return Truth(
        header=Header(stamp_ns=i * 100_000_000, frame_id="local_enu", source="test/pub", seq=i),
        platform="auv9",
        position_m=[100.0 + i, 2000.0 - 3.0 * i, -20.0],
    )


def fix(i: int) -> Fix:
    return Fix(
        header=Header(stamp_ns=i * 100_000_000, frame_id="local_enu", source="test/est", seq=i),
        platform="auv9",
        estimator="test",
        status="TRACKING",
        valid=True,
        estimate=gaussian("local_enu", POSITION, [101.0 + i, 1998.0 - 3.0 * i, -21.0], COV),
    )


class Publisher:
    """Publishes truth and fixes every 50 ms on the router until stopped; remembers what it sent."""

    def __init__(self, router: str) -> None:
        self.session = open_session(ZenohSettings(mode="client", connect=[router]))
        self.sent: dict[str, list[Any]] = {TRUTH_KEY: [], FIX_KEY: []}
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        i = 0
        while not self.stop.is_set():
            for key, msg in ((TRUTH_KEY, truth(i)), (FIX_KEY, fix(i))):
                self.sent[key].append(msg)  # remembered first: a reader may compare as soon as it is delivered
                self.session.put(key, codec.encode(msg), encoding=zenoh.Encoding(codec.encoding_of(type(msg))))
            i += 1
            self.stop.wait(0.05)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        self.session.close()


async def collect(
    url: str,
    wanted: list[str],
    n_each: int,
    timeout: float,
    subprotocol: str = "foxglove.sdk.v1",
    origin: str | None = None,
    advertised: list[dict[str, Any]] | None = None,
) -> tuple[dict[str, Any], dict[str, list[bytes]]]:
    """Connect, subscribe to the wanted topics once advertised; (advertised channels by topic, payloads per topic).
    ``advertised`` receives every advertised channel (two channels may share a topic)."""
    import websockets

    channels: dict[str, Any] = {}
    got: dict[str, list[bytes]] = {t: [] for t in wanted}
    sub_topic: dict[int, str] = {}
    deadline = time.monotonic() + timeout
    async with websockets.connect(url, subprotocols=[subprotocol], origin=origin) as ws:  # type: ignore[list-item,arg-type]
        assert ws.subprotocol == subprotocol
        first = json.loads(await asyncio.wait_for(ws.recv(), timeout))
        assert first["op"] == "serverInfo" and first["name"] == "fixstream"
        while time.monotonic() < deadline and any(len(v) < n_each for v in got.values()):
            try:
                frame = await asyncio.wait_for(ws.recv(), max(0.1, deadline - time.monotonic()))
            except TimeoutError:
                break
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "advertise":
                    subs = []
                    for ch in msg["channels"]:
                        channels[ch["topic"]] = ch
                        if advertised is not None:
                            advertised.append(ch)
                        if ch["topic"] in wanted:
                            sid = len(sub_topic) + 1
                            sub_topic[sid] = ch["topic"]
                            subs.append({"id": sid, "channelId": ch["id"]})
                    if subs:
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                continue
            opcode, sid, _ = struct.unpack("<BIQ", frame[:13])
            if opcode == 1 and sid in sub_topic:
                got[sub_topic[sid]].append(bytes(frame[13:]))
    return channels, got


def collect_reconnecting(
    url: str, wanted: list[str], n_each: int, timeout: float, advertised: list[dict[str, Any]]
) -> tuple[dict[str, Any], dict[str, list[bytes]]]:
    """:func:`collect` while channels are still being created: a channel created while a client connects can miss
    that client's advertisements (seen in CI: a topic never advertised in 30 s while the others streamed), so a
    connection that has not seen every wanted topic advertised within 8 s is replaced by a new one (whose first
    advertisement lists every existing channel). Payloads of every connection are kept."""
    channels: dict[str, Any] = {}
    got: dict[str, list[bytes]] = {t: [] for t in wanted}
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and any(len(v) < n_each for v in got.values()):
        ch, g = asyncio.run(collect(url, wanted, n_each, min(8.0, deadline - time.monotonic()), advertised=advertised))
        channels.update(ch)
        for t, payloads in g.items():
            got[t].extend(payloads)
    return channels, got


def test_client_receives_zenoh_messages_through_the_bridge(router: str, tmp_path: Path) -> None:
    scenario = yaml.safe_load((REPO / "scenarios" / "demo.yaml").read_text())
    scenario.update(name="bridge_test", origin=ORIGIN)
    path = tmp_path / "bridge_test.yaml"
    path.write_text(yaml.safe_dump(scenario))
    proc = subprocess.Popen(
        fixstream_cmd("foxglove", "--port", "0", "--connect", router, "--scenario", str(path)),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    publisher = None
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("foxglove: ws://127.0.0.1:"), (
            line,
            proc.stderr.read() if proc.poll() is not None else "",
        )
        url = line.split()[1]
        publisher = Publisher(router)
        scene, loc = "/foxglove/scene/fix/test/auv9", "/foxglove/location/fix/test/auv9"
        wanted = [TRUTH_KEY, scene, loc, "/foxglove/scene/truth/auv9"]
        channels, got = asyncio.run(collect(url, wanted, 5, timeout=30.0))
    finally:
        if publisher is not None:
            publisher.close()
        proc.terminate()
        out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err[-3000:]
    assert "foxglove: served" in out
    for topic in wanted:
        assert len(got[topic]) >= 5, (topic, {t: len(v) for t, v in got.items()})
    # the raw channel: the message's JSON with its JSON Schema, equal to one that was published
    raw = channels[TRUTH_KEY]
    assert raw["schemaName"] == "fixstream.Truth" and raw["encoding"] == "json"
    assert raw["schemaEncoding"] == "jsonschema" and json.loads(raw["schema"])["title"] == "Truth"
    sent = {m.header.seq: m for m in publisher.sent[TRUTH_KEY]}
    for payload in got[TRUTH_KEY]:
        m = Truth.model_validate_json(payload, strict=True)
        assert m == sent[m.header.seq]
    # the scene: Foxglove's schema, the published position and covariance
    ch = channels[scene]
    assert ch["schemaName"] == "foxglove.SceneUpdate" and ch["encoding"] == "protobuf"
    update_cls = proto_class("foxglove.SceneUpdate", base64.b64decode(ch["schema"]))
    fixes = {m.header.stamp_ns: m for m in publisher.sent[FIX_KEY]}
    for payload in got[scene]:
        (entity,) = update_cls.FromString(payload).entities
        stamp = entity.timestamp.seconds * 10**9 + entity.timestamp.nanos
        f = fixes[stamp]
        p = entity.spheres[0].pose.position
        assert [p.x, p.y, p.z] == pytest.approx(f.estimate.mean, abs=1e-9)
        assert np.allclose(cov_of_sphere(entity.spheres[0]), np.array(COV), atol=1e-9)
    # the map: the fix on WGS84, which closed-form geodesy takes back to its ENU position
    loc_cls = proto_class("foxglove.LocationFix", base64.b64decode(channels[loc]["schema"]))
    origin = Origin(ORIGIN["lat_deg"], ORIGIN["lon_deg"], ORIGIN["alt_m"])
    for payload in got[loc]:
        lf = loc_cls.FromString(payload)
        f = fixes[lf.timestamp.seconds * 10**9 + lf.timestamp.nanos]
        lla = (np.array([lf.latitude]), np.array([lf.longitude]), np.array([lf.altitude]))
        enu = enu_independent(*lla, origin)[0]  # type: ignore[arg-type]
        assert np.allclose(enu, f.estimate.mean, rtol=0.0, atol=GEODESY_ATOL_M)
        assert list(lf.position_covariance) == pytest.approx([v for row in COV for v in row])


# ----- issue 17, item 8 -----------------------------------------------------------------------------------------
SITE_KEY = "fixstream/sensor/r9/radar/plots/site"
PLOT_KEY = "fixstream/sensor/r9/radar/plots"


class StreamPublisher(Publisher):
    """As :class:`Publisher`, plus a start marker naming ``scenario``, a radar's plots and site, and a stray second
    model (a ``Heading``) on the plots key, each round."""

    def __init__(self, router: str, scenario: str) -> None:
        from samples import EXAMPLES

        example = EXAMPLES["ScenarioMarker"]
        # a player's marker: the recorder opens a run (and loads the scenario's origin) only on a player's start
        header = example.header.model_copy(update={"source": "player/bridge", "seq": 0})
        self.marker = example.model_copy(update={"scenario": scenario, "event": "start", "header": header})
        self.plot, self.site, self.stray = EXAMPLES["RadarPlot"], EXAMPLES["RadarSite"], EXAMPLES["Heading"]
        super().__init__(router)

    def _run(self) -> None:
        i = 0
        while not self.stop.is_set():
            for key, msg in (
                (keys.scenario(self.marker.scenario), self.marker),
                (TRUTH_KEY, truth(i)),
                (FIX_KEY, fix(i)),
                (PLOT_KEY, self.plot),
                (SITE_KEY, self.site),
                (PLOT_KEY, self.stray),
            ):
                self.session.put(key, codec.encode(msg), encoding=zenoh.Encoding(codec.encoding_of(type(msg))))
            i += 1
            self.stop.wait(0.05)


def _start_bridge(router: str, *extra: str) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen(
        fixstream_cmd("foxglove", "--port", "0", "--connect", router, *extra),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line.startswith("foxglove: ws://127.0.0.1:"), (line, proc.stderr.read() if proc.poll() is not None else "")
    return proc, line.split()[1]


async def _handshake_status(url: str, subprotocol: str, origin: str | None) -> int:
    """101 when the bridge accepts the handshake, else the HTTP status it answers."""
    import websockets
    from websockets.exceptions import InvalidStatus

    try:
        async with websockets.connect(url, subprotocols=[subprotocol], origin=origin, open_timeout=10):  # type: ignore[list-item,arg-type]
            return 101
    except InvalidStatus as exc:
        return int(exc.response.status_code)


def _non_loopback_address() -> str | None:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # no packet is sent: the routing table names the outgoing address
        except OSError:
            return None
        address = str(s.getsockname()[0])
    return None if address.startswith("127.") else address


def test_both_subprotocols_origin_check_and_loopback_only(router: str) -> None:
    proc, url = _start_bridge(router, "--allow-origin", "https://app.foxglove.dev/")
    publisher = None
    try:
        publisher = Publisher(router)
        # Lichtblick's subprotocol only: the channels are listed and the messages arrive
        channels, got = asyncio.run(collect(url, [TRUTH_KEY], 3, timeout=30.0, subprotocol="foxglove.websocket.v1"))
        assert {TRUTH_KEY, FIX_KEY} <= set(channels)
        sent = {m.header.seq: m for m in publisher.sent[TRUTH_KEY]}
        assert len(got[TRUTH_KEY]) >= 3
        for payload in got[TRUTH_KEY]:
            m = Truth.model_validate_json(payload, strict=True)
            assert m == sent[m.header.seq]
        # an allowed page (Origin compared without case or trailing slash), and a native client with no Origin
        _, got = asyncio.run(collect(url, [FIX_KEY], 1, timeout=30.0, origin="https://APP.foxglove.dev"))
        assert got[FIX_KEY]
        statuses = {
            (proto, origin): asyncio.run(_handshake_status(url, proto, origin))
            for proto in ("foxglove.sdk.v1", "foxglove.websocket.v1")
            for origin in (None, "https://evil.example", "null", "https://app.foxglove.dev.evil.example")
        }
        assert statuses == {
            (proto, origin): 101 if origin is None else 403
            for proto in ("foxglove.sdk.v1", "foxglove.websocket.v1")
            for origin in (None, "https://evil.example", "null", "https://app.foxglove.dev.evil.example")
        }
        assert asyncio.run(_handshake_status(url, "some.other.v1", None)) == 400
        # listening on loopback only: this host's other address does not answer
        address = _non_loopback_address()
        if address is not None:
            port = int(url.rsplit(":", 1)[1])
            with pytest.raises(OSError):
                import socket

                socket.create_connection((address, port), timeout=2).close()
    finally:
        if publisher is not None:
            publisher.close()
        proc.terminate()
        out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err[-3000:]
    assert "6 refused (Origin not allowed)" in out, out  # 2 subprotocols x 3 foreign origins
    assert err.count("refused a client from Origin https://evil.example") == 2, err
    assert "--allow-origin https://evil.example" in err


def test_bridge_topics_equal_the_recordings(router: str, tmp_path: Path) -> None:
    """The recorder (with its Foxglove channels) and the bridge on one stream: the same topics, one per key."""
    from conftest import service_env, wait_until

    from shared.mcap_io import iter_records, recording_files

    scenario = yaml.safe_load((REPO / "scenarios" / "demo.yaml").read_text())
    scenario["simulators"] = [sim for sim in scenario["simulators"] if sim["kind"] == "nav_platform"]
    scenario.update(name="bridge_topics", origin=ORIGIN, estimators=[])  # quick to load: no estimator plugins
    (tmp_path / "bridge_topics.yaml").write_text(yaml.safe_dump(scenario))
    env = service_env(
        router,
        FIXSTREAM_RECORDER_INSTANCE="fx",
        FIXSTREAM_RECORDER_OUT_DIR=str(tmp_path / "rec"),
        FIXSTREAM_RECORDER_FOXGLOVE="true",
        FIXSTREAM_RECORDER_SCENARIOS_DIR=str(tmp_path),
    )
    recorder = subprocess.Popen(fixstream_cmd("run", "recorder"), env=env, cwd=REPO, text=True)
    proc, url = _start_bridge(router, "--scenarios-dir", str(tmp_path))
    publisher = None
    try:
        session = open_session(ZenohSettings(mode="client", connect=[router]))
        alive = lambda: list(session.liveliness().get("fixstream/alive/recorder/fx", timeout=0.5))  # noqa: E731
        assert wait_until(lambda: len(alive()) == 1, timeout=30)
        session.close()
        publisher = StreamPublisher(router, "bridge_topics")
        scene = "/foxglove/scene/fix/test/auv9"
        advertised: list[dict[str, Any]] = []
        channels, got = collect_reconnecting(url, [scene, SITE_KEY], 3, timeout=30.0, advertised=advertised)
        assert len(got[scene]) >= 3 and len(got[SITE_KEY]) >= 3
        publisher.stop.set()
        publisher.thread.join(5)
        time.sleep(0.5)  # the last messages reach the recorder
    finally:
        if publisher is not None:
            publisher.close()
        recorder.terminate()
        recorder.wait(timeout=30)
        proc.terminate()
        proc.communicate(timeout=20)
    recorded = {r.topic for f in recording_files(tmp_path / "rec") for r in iter_records(f)}
    # the recorder's own diagnostics (it counts the repeated example seq numbers) are on the bus, not in its file
    served = {t for t in channels if not t.startswith("fixstream/diag/recorder/")}
    recorded = {t for t in recorded if not t.startswith("fixstream/diag/recorder/")}
    assert {PLOT_KEY, SITE_KEY, TRUTH_KEY, FIX_KEY, scene} <= recorded
    assert served == recorded
    assert not [t for t in channels if "[" in t]  # no renamed topic
    schemas = {(ch["topic"], ch["schemaName"]) for ch in advertised}
    assert {s for t, s in schemas if t == SITE_KEY} == {"fixstream.RadarSite"}
    # a second model on one key: a second channel of the same topic, as the recorder writes it
    assert {s for t, s in schemas if t == PLOT_KEY} == {"fixstream.RadarPlot", "fixstream.Heading"}
