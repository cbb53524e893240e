"""``fixstream pki DIR``: a certificate authority and one certificate per identity of the secure stack.

Writes ``DIR/ca.pem`` and ``DIR/<identity>.pem`` + ``.key`` for every identity the router's access control knows
(router, player, recorder, coordinator, attitude, lbl_nav, pcl_tracker, rd_nav, terrain_nav, client). A process
uses its identity with ``FIXSTREAM_ZENOH_TLS_ROOT_CA=DIR/ca.pem FIXSTREAM_ZENOH_TLS_CERT=DIR/<identity>.pem
FIXSTREAM_ZENOH_TLS_KEY=DIR/<identity>.key`` and a ``tls/HOST:PORT`` endpoint; the router runs with
``fixstream router --listen tls/0.0.0.0:7447 --config ACL`` and its own identity, ACL being the access control
installed with fixstream (``tools/stack/router-secure.json5``; the command prints its installed path).
Containers: ``compose.secure.yaml`` (docs/stack.md).

A directory that already holds a CA (``ca.pem``) is left untouched (exit status 2): a new CA would void every
certificate deployed from the old one. ``--force`` replaces the CA and every certificate and key.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("directory", type=Path, help="where to write the CA, certificates and keys")
    parser.add_argument("--days", type=int, default=365, help="validity of every certificate, days (default: 365)")
    parser.add_argument(
        "--force", action="store_true", help="replace an existing CA and every certificate and key in DIRECTORY"
    )


def run(args: argparse.Namespace) -> int:
    import sys

    from ..stack.pki import IDENTITIES, ROUTER_ACL, PkiExists, make_pki
    from . import exit_codes

    if args.days < 1:
        print("fixstream pki: --days must be >= 1", file=sys.stderr)
        return exit_codes.USAGE
    try:
        pki = make_pki(args.directory, days=args.days, force=args.force)
    except PkiExists as exc:
        print(f"fixstream pki: {exc}: not replaced (--force replaces it and voids its certificates)", file=sys.stderr)
        return exit_codes.USAGE
    except OSError as exc:
        print(f"fixstream pki: {args.directory}: {exc.strerror or exc}", file=sys.stderr)
        return exit_codes.USAGE
    print(f"wrote {pki.ca} and certificates for {', '.join(IDENTITIES)} in {pki.directory}")
    print(f"the router's access control: {ROUTER_ACL}")
    return 0
