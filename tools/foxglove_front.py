"""The WebSocket front of ``fixstream foxglove``: Origin check, both Foxglove subprotocols, relay to the SDK server.

foxglove-sdk's server (``foxglove.start_server``, Rust) speaks the Foxglove WebSocket protocol well but offers no
say over two things a bridge on a workstation needs:

* **subprotocols**: it accepts only ``foxglove.sdk.v1``; Lichtblick and older Foxglove clients ask for
  ``foxglove.websocket.v1`` and get HTTP 400. The two names carry the same protocol today (Foxglove's stated
  position, which Lichtblick's and Flora's clients rely on: they added ``foxglove.sdk.v1`` as a second name, nothing
  else), so the front accepts either and passes frames through unchanged.
* **Origin**: any web page open in a local browser may open a WebSocket to ``ws://127.0.0.1:8765`` and read the
  stream (browsers apply no same-origin rule to WebSockets; they send the page's ``Origin`` and leave the check to
  the server). The front refuses a handshake whose ``Origin`` is not one the user allowed (``--allow-origin``) with
  HTTP 403, and accepts clients that send no ``Origin`` (native programs: Python, the ``foxglove`` CLI, ...).

So the SDK server runs on a private loopback port, and this front (the ``websockets`` package, asyncio, on its own
thread) listens where the user asked (127.0.0.1 by default), checks each handshake, opens one upstream connection
per accepted client and relays every frame both ways (text as text, binary as binary, no recompression). Flow
control stays the SDK's: a slow client slows its relay, the SDK's per-client backlog then drops the oldest data
messages as it does for a direct client.

The private port must not be a way around the check: a page could scan loopback ports. The SDK server therefore
listens with TLS (``wss://``) on a certificate made for this run and kept in memory, which only the front trusts; a
browser refuses a certificate it does not trust and offers no way past it for a WebSocket, so no page reaches the
SDK server. (A local native program could, with verification off; such clients are allowed through the front
anyway.)
"""

from __future__ import annotations

import asyncio
import datetime as dt
import ipaddress
import logging
import ssl
import threading
from collections import Counter
from dataclasses import dataclass
from http import HTTPStatus
from typing import Any

log = logging.getLogger("fixstream.foxglove")

#: subprotocols the front accepts, in order of preference (a client offering both gets the first)
SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
#: the one subprotocol the SDK server speaks
UPSTREAM_SUBPROTOCOL = "foxglove.sdk.v1"
#: ``--allow-origin`` value that turns the Origin check off
ANY_ORIGIN = "*"
#: largest frame a client may send (subscribe, advertise, client publish), bytes
MAX_CLIENT_FRAME = 16 << 20


@dataclass(frozen=True)
class UpstreamTls:
    """A certificate for 127.0.0.1 made for one run: the SDK server's ``tls_cert``/``tls_key`` and the front's
    client context that trusts exactly it."""

    cert_pem: bytes
    key_pem: bytes

    @classmethod
    def make(cls) -> UpstreamTls:
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes, serialization
        from cryptography.hazmat.primitives.asymmetric import ec
        from cryptography.x509.oid import NameOID

        key = ec.generate_private_key(ec.SECP256R1())
        name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "fixstream foxglove bridge (loopback)")])
        now = dt.datetime.now(dt.UTC) - dt.timedelta(minutes=5)
        cert = (
            x509.CertificateBuilder()
            .subject_name(name)
            .issuer_name(name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now)
            .not_valid_after(now + dt.timedelta(days=30))
            .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), False)
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .sign(key, hashes.SHA256())
        )
        return cls(
            cert.public_bytes(serialization.Encoding.PEM),
            key.private_bytes(
                serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
            ),
        )

    def client_context(self) -> ssl.SSLContext:
        ctx = ssl.create_default_context(cadata=self.cert_pem.decode())
        ctx.check_hostname = True
        return ctx


def normalise_origin(origin: str) -> str:
    """Origins compare case-insensitively, without a trailing slash (``https://App.Foxglove.dev/`` -> ``https://app
    .foxglove.dev``)."""
    return origin.strip().rstrip("/").lower()


class OriginPolicy:
    """Which ``Origin`` headers may open a connection: none at all (native clients) always, and the listed ones."""

    def __init__(self, allowed: list[str] | tuple[str, ...] = ()) -> None:
        self.any = ANY_ORIGIN in allowed
        self.allowed = frozenset(normalise_origin(o) for o in allowed if o != ANY_ORIGIN)

    def allows(self, origins: list[str]) -> bool:
        """``origins``: every Origin header of the handshake (none: a native client)."""
        if not origins:
            return True
        if len(origins) > 1:
            return False  # a browser sends one; two are a forgery
        return self.any or normalise_origin(origins[0]) in self.allowed


class Front:
    """The listening side of the bridge (see the module docstring). ``start()`` binds and returns the port."""

    def __init__(self, host: str, port: int, upstream_port: int, tls: UpstreamTls, origins: OriginPolicy) -> None:
        self.host = host
        self.port = port
        self.upstream_url = f"wss://127.0.0.1:{upstream_port}"
        self.upstream_ssl = tls.client_context()
        self.origins = origins
        #: handshakes refused per reason (``origin``), connections relayed per subprotocol
        self.refused: Counter[str] = Counter()
        self.accepted: Counter[str] = Counter()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping: asyncio.Event | None = None
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    # ----- life cycle ---------------------------------------------------------------------------------------------
    def start(self, timeout: float = 10.0) -> int:
        """Listen on ``host:port`` (0: a free port); returns the port. Raises OSError if it cannot bind."""
        ready = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(ready,), name="foxglove-front", daemon=True)
        self._thread.start()
        if not ready.wait(timeout):
            raise OSError(f"the WebSocket front did not start within {timeout:g} s")
        if self._error is not None:
            raise self._error
        return self.port

    def stop(self, timeout: float = 5.0) -> None:
        if self._loop is not None and self._stopping is not None:
            self._loop.call_soon_threadsafe(self._stopping.set)
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def _run(self, ready: threading.Event) -> None:
        self._loop = asyncio.new_event_loop()
        try:
            self._loop.run_until_complete(self._serve(ready))
        except BaseException as exc:  # bind errors: handed to start()
            self._error = exc
            ready.set()
        finally:
            self._loop.close()

    async def _serve(self, ready: threading.Event) -> None:
        from websockets.asyncio.server import serve

        self._stopping = asyncio.Event()
        async with serve(
            self._relay,
            self.host,
            self.port,
            subprotocols=list(SUBPROTOCOLS),  # type: ignore[arg-type]
            process_request=self._check_origin,
            compression=None,
            max_size=MAX_CLIENT_FRAME,
        ) as server:
            self.port = int(next(iter(server.sockets)).getsockname()[1])
            ready.set()
            await self._stopping.wait()

    # ----- one client ---------------------------------------------------------------------------------------------
    def _check_origin(self, connection: Any, request: Any) -> Any:
        origins = request.headers.get_all("Origin")
        if self.origins.allows(origins):
            return None
        self.refused["origin"] += 1
        if self.refused["origin"] <= 10 or self.refused["origin"] % 100 == 0:
            log.warning(
                "foxglove: refused a client from Origin %s (%d refused); to allow it: --allow-origin %s",
                ", ".join(origins),
                self.refused["origin"],
                origins[0] if len(origins) == 1 else "ORIGIN",
            )
        return connection.respond(HTTPStatus.FORBIDDEN, "this bridge does not serve pages from your Origin\n")

    async def _relay(self, client: Any) -> None:
        from websockets.asyncio.client import connect
        from websockets.exceptions import ConnectionClosed, InvalidHandshake

        self.accepted[str(client.subprotocol)] += 1
        try:
            async with connect(
                self.upstream_url,
                subprotocols=[UPSTREAM_SUBPROTOCOL],  # type: ignore[list-item]
                ssl=self.upstream_ssl,
                compression=None,
                max_size=None,
                open_timeout=10,
            ) as server:
                await _pipe_both_ways(client, server)
        except (OSError, InvalidHandshake, TimeoutError) as exc:
            log.warning("foxglove: the SDK server did not take a connection: %s", exc)
            await client.close(1011, "upstream unavailable")
        except ConnectionClosed:
            pass


async def _pipe_both_ways(a: Any, b: Any) -> None:
    """Relay frames a -> b and b -> a until either side closes; then close the other."""
    from websockets.exceptions import ConnectionClosed

    async def pipe(src: Any, dst: Any) -> None:
        try:
            async for frame in src:
                await dst.send(frame)
        except ConnectionClosed:
            pass

    tasks = [asyncio.create_task(pipe(a, b)), asyncio.create_task(pipe(b, a))]
    _, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    for t in pending:
        t.cancel()
    await asyncio.gather(*pending, return_exceptions=True)
    await asyncio.gather(a.close(), b.close(), return_exceptions=True)


__all__ = ["ANY_ORIGIN", "SUBPROTOCOLS", "Front", "OriginPolicy", "UpstreamTls"]
