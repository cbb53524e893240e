"""A certificate authority and one certificate per identity of the stack, for mutual TLS (``fixstream pki``,
``fixstream up --secure``).

Every process of the secure stack proves who it is with a certificate whose common name is its identity; the
router's access-control rules (``tools/stack/router-secure.json5``) say which identity may publish on which keys.
Identities are roles, not instances: ``player``, ``recorder``, ``coordinator``, one per estimator kind
(``attitude``, ``lbl_nav``, ``pcl_tracker``, ``rd_nav``, ``terrain_nav``) and ``client`` (read only: echo, status,
the Foxglove bridge). The router's certificate names the hosts clients reach it by (``localhost``, ``router``
under compose, 127.0.0.1). Keys are ECDSA P-256, certificates valid for ``days``.

Layout of the directory: ``ca.pem`` and ``<identity>.pem`` + ``<identity>.key`` (private keys mode 0600).
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

#: every identity the repository's router configuration knows
IDENTITIES = (
    "router",
    "player",
    "recorder",
    "coordinator",
    "attitude",
    "lbl_nav",
    "pcl_tracker",
    "rd_nav",
    "terrain_nav",
    "client",
)
ROUTER_HOSTS = ("localhost", "router", "127.0.0.1", "::1")
#: the router's access-control configuration: package data beside this module (pyproject.toml), so it resolves the
#: same in a checkout, an editable install, a wheel and the image (``fixstream pki`` prints where it is)
ROUTER_ACL = Path(__file__).resolve().with_name("router-secure.json5")


@dataclass(frozen=True)
class Identity:
    name: str
    cert: Path
    key: Path


@dataclass(frozen=True)
class Pki:
    directory: Path
    ca: Path

    def identity(self, name: str) -> Identity:
        return Identity(name, self.directory / f"{name}.pem", self.directory / f"{name}.key")


def _name(cn: str) -> x509.Name:
    return x509.Name(
        [x509.NameAttribute(NameOID.COMMON_NAME, cn), x509.NameAttribute(NameOID.ORGANIZATION_NAME, "fixstream")]
    )


def _write_key(path: Path, key: ec.EllipticCurvePrivateKey) -> None:
    path.write_bytes(
        key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    )
    os.chmod(path, 0o600)


class PkiExists(FileExistsError):
    """The directory already holds a CA: replacing it would void every certificate it signed."""


def make_pki(directory: Path, identities: tuple[str, ...] = IDENTITIES, days: int = 30, force: bool = True) -> Pki:
    """A fresh CA and a certificate for each identity in ``directory`` (created; existing files replaced). With
    ``force`` False, a directory that already holds ``ca.pem`` raises :class:`PkiExists` and is left untouched."""
    directory.mkdir(parents=True, exist_ok=True, mode=0o700)
    if not force and (directory / "ca.pem").exists():
        raise PkiExists(f"{directory} already holds a CA ({directory / 'ca.pem'})")
    now = dt.datetime.now(dt.UTC) - dt.timedelta(minutes=5)
    until = now + dt.timedelta(days=days)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = _name("fixstream CA")
    ca = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(until)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .sign(ca_key, hashes.SHA256())
    )
    (directory / "ca.pem").write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    for name in identities:
        key = ec.generate_private_key(ec.SECP256R1())
        hosts = ROUTER_HOSTS if name == "router" else ("localhost",)
        sans: list[x509.GeneralName] = []
        for host in hosts:
            try:
                sans.append(x509.IPAddress(ipaddress.ip_address(host)))
            except ValueError:
                sans.append(x509.DNSName(host))
        cert = (
            x509.CertificateBuilder()
            .subject_name(_name(name))
            .issuer_name(ca_name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now)
            .not_valid_after(until)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName(sans), critical=False)
            .add_extension(
                x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                critical=False,
            )
            .sign(ca_key, hashes.SHA256())
        )
        (directory / f"{name}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        _write_key(directory / f"{name}.key", key)
    return Pki(directory, directory / "ca.pem")
