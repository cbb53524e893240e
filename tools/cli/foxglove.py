"""``fixstream foxglove``: a live bridge from the Zenoh streams to the Foxglove app (Foxglove WebSocket protocol).

Subscribes to ``--key`` (default ``fixstream/**``) and serves every message on a Foxglove WebSocket server
(the ``foxglove-sdk`` package) at ``ws://HOST:PORT``: each key as itself, on a channel named exactly as the
recorder's MCAP names it (the key; JSON with its JSON Schema) and, for fixes, tracks and truth, the same Foxglove
scene (``/foxglove/scene/<key>``, ``foxglove.SceneUpdate`` with 3σ ellipsoids) and map
(``/foxglove/location/<key>``, ``foxglove.LocationFix``) channels as the recorder's MCAP. In Foxglove: *Open
connection* → *Foxglove WebSocket* → the printed URL.

Clients may speak either subprotocol name of the protocol, ``foxglove.sdk.v1`` (Foxglove) or
``foxglove.websocket.v1`` (Lichtblick, older Foxglove). The bridge listens on 127.0.0.1 unless ``--host`` says
otherwise, and refuses (HTTP 403) a browser page whose ``Origin`` is not allowed with ``--allow-origin`` (e.g.
``--allow-origin https://app.foxglove.dev`` for Foxglove's web app); clients that send no ``Origin`` (native
programs, the desktop apps' own connections) are served. Details: docs/clients.md.

Frames and the map's geodetic origin come from the scenario the player's start marker names (looked up in
``--scenarios-dir``), or from ``--scenario``. Runs until Ctrl-C / SIGTERM. Once the server listens it prints
``foxglove: ws://HOST:PORT`` (``--port 0`` picks a free port).
"""

from __future__ import annotations

import argparse

from .common import add_zenoh_arguments, key_expr, port_number, seconds


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (0.0.0.0: every interface)")
    parser.add_argument("--port", type=port_number, default=8765, help="WebSocket port (0: a free one)")
    parser.add_argument(
        "--allow-origin",
        action="append",
        default=[],
        metavar="ORIGIN",
        help="also serve browser pages from this Origin, e.g. https://app.foxglove.dev (repeatable; '*': any page);"
        " clients without an Origin header are always served",
    )
    parser.add_argument("--key", type=key_expr, default="fixstream/**", help="Zenoh key expression to serve")
    parser.add_argument("--scenario", help="scenario .yaml (or name) for the frames and the map origin")
    parser.add_argument("--scenarios-dir", help="where start markers' scenarios are looked up (default scenarios)")
    parser.add_argument("--no-raw", action="store_true", help="serve only the Foxglove scene and map channels")
    parser.add_argument("--timeout", type=seconds, default=0.0, help="exit after this many seconds (0: never)")
    add_zenoh_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import signal
    import sys
    import threading
    import time

    import foxglove

    from services.player.scenario import load_by_name
    from shared.foxglove.convert import Converter
    from shared.session import open_session
    from tools.foxglove_bridge import Bridge
    from tools.foxglove_front import Front, OriginPolicy, UpstreamTls

    from . import exit_codes
    from .common import zenoh_settings_from

    converter = Converter(scenarios_dir=args.scenarios_dir, scenario_loader=load_by_name)
    if args.scenario:
        from services.player.scenario import ScenarioError, load_scenario, resolve

        try:
            converter = Converter.for_scenario(load_scenario(resolve(args.scenario, args.scenarios_dir)))
        except ScenarioError as exc:
            print(f"fixstream foxglove: {exc}", file=sys.stderr)
            return exit_codes.USAGE
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    context = foxglove.Context()
    tls = UpstreamTls.make()
    try:  # the SDK's server on a private loopback port, over TLS only the front trusts (tools/foxglove_front.py)
        server = foxglove.start_server(
            name="fixstream", host="127.0.0.1", port=0, context=context, tls_cert=tls.cert_pem, tls_key=tls.key_pem
        )
    except Exception as exc:  # the SDK raises its own error types
        print(f"fixstream foxglove: cannot start the Foxglove server: {exc}", file=sys.stderr)
        return exit_codes.FAILURE
    front = Front(args.host, args.port, server.port, tls, OriginPolicy(args.allow_origin))
    try:
        port = front.start()
    except OSError as exc:  # address in use, no such interface
        server.stop()
        print(f"fixstream foxglove: cannot serve on {args.host}:{args.port}: {exc}", file=sys.stderr)
        return exit_codes.USAGE
    bridge = Bridge(converter, raw=not args.no_raw, context=context)
    bridge.start()
    try:
        session = open_session(zenoh_settings_from(args))
    except BaseException:
        bridge.stop()
        front.stop()
        server.stop()
        raise
    sub = session.declare_subscriber(
        args.key, lambda s: bridge.on_sample(str(s.key_expr), s.payload.to_bytes(), str(s.encoding))
    )
    host = f"[{args.host}]" if ":" in args.host else args.host
    print(f"foxglove: ws://{host}:{port} (serving {args.key})", flush=True)
    deadline = time.monotonic() + args.timeout if args.timeout > 0 else float("inf")
    try:
        while not stop.is_set() and time.monotonic() < deadline:
            stop.wait(0.2)
    finally:
        sub.undeclare()
        session.close()
        bridge.stop()
        front.stop()
        server.stop()
    errors = sum(bridge.errors.values())
    refused = sum(front.refused.values())
    print(
        f"foxglove: served {sum(bridge.published.values())} messages on {len(bridge.published)} channels"
        f" to {sum(front.accepted.values())} connections"
        + (f", {refused} refused (Origin not allowed)" if refused else "")
        + (f", {errors} samples skipped: {dict(bridge.errors)}" if errors else ""),
        flush=True,
    )
    return exit_codes.OK
