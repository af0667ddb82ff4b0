"""`pure-hil certs init DIR`: a certificate authority and one certificate per bench role, for the bench
router's mutual TLS (docs/security.md). The router's ACL identifies a client by its certificate's common
name, so each role gets CN=<role>. Keys are written 0600 in a 0700 folder; nothing here is ever committed.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

ROLES = ("operator", "sc-agent", "tes", "rig", "controller", "supervisor", "monitor", "fault-injector")
"""Client roles (docs/security.md lists what each may put and read)."""
ROUTER = "router"


def _name(common_name: str) -> x509.Name:
    return x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, "pure-hil bench"),
            x509.NameAttribute(NameOID.COMMON_NAME, common_name),
        ]
    )


def _write_key(path: Path, key: ec.EllipticCurvePrivateKey) -> None:
    pem = key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(pem)
    os.chmod(path, 0o600)  # also when the file existed with looser bits


def _issue(
    subject: str,
    key: ec.EllipticCurvePrivateKey,
    issuer: x509.Name,
    issuer_key: ec.EllipticCurvePrivateKey,
    days: int,
    ca: bool = False,
    server: bool = False,
    hosts: tuple[str, ...] = ("127.0.0.1",),
) -> x509.Certificate:
    now = datetime.datetime.now(datetime.UTC)
    builder = (
        x509.CertificateBuilder()
        .subject_name(_name(subject))
        .issuer_name(issuer)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=ca, path_length=0 if ca else None), critical=True)
    )
    if ca:
        builder = builder.add_extension(
            x509.KeyUsage(False, False, False, False, False, True, True, False, False), critical=True
        )
    else:
        usage = [ExtendedKeyUsageOID.SERVER_AUTH] if server else [ExtendedKeyUsageOID.CLIENT_AUTH]
        builder = builder.add_extension(x509.ExtendedKeyUsage(usage), critical=False)
    if server:
        # zenoh verifies the router's name on connect: every address it is reached at must be in the SAN.
        alt = [x509.IPAddress(ipaddress.ip_address(h)) for h in hosts] + [x509.DNSName("localhost")]
        builder = builder.add_extension(x509.SubjectAlternativeName(alt), critical=False)
    return builder.sign(issuer_key, hashes.SHA256())


def init(
    folder: Path | str, days: int = 365, force: bool = False, roles=ROLES, hosts: list[str] | None = None
) -> dict[str, Path]:
    """Write ca.pem/ca.key, router.pem/router.key and <role>.pem/<role>.key; returns the certificate paths.
    `hosts`: the addresses the router is reached at (its certificate names them; default 127.0.0.1)."""
    names = tuple(hosts or ("127.0.0.1",))
    for host in names:
        ipaddress.ip_address(host)  # ValueError names a bad address before anything is written
    folder = Path(folder)
    if folder.exists() and any(folder.iterdir()) and not force:
        raise FileExistsError(f"{folder} is not empty: pass --force to replace its certificates")
    folder.mkdir(parents=True, exist_ok=True)
    os.chmod(folder, 0o700)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = _name("pure-hil bench CA")
    ca = _issue("pure-hil bench CA", ca_key, ca_name, ca_key, days, ca=True)
    _write_key(folder / "ca.key", ca_key)
    (folder / "ca.pem").write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    out = {"ca": folder / "ca.pem"}
    for name in (ROUTER, *roles):
        key = ec.generate_private_key(ec.SECP256R1())
        cert = _issue(name, key, ca_name, ca_key, days, server=name == ROUTER, hosts=names)
        _write_key(folder / f"{name}.key", key)
        (folder / f"{name}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        out[name] = folder / f"{name}.pem"
    return out
