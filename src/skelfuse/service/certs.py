"""``skelfuse certs``: a rig's certificate authority and one certificate per process identity.

Uses the ``cryptography`` library (X.509 and keys done right is not code to write ourselves). Layout of the
output directory, what ``[zenoh.tls] directory`` points at::

    ca.pem, ca.key                         the rig's CA (keep ca.key off the rig's PCs once certificates exist)
    router.pem, router.key                 the zenoh router (``skelfuse router``)
    fusion.pem, fusion.key                 the fusion node
    capture-<host>.pem, .key               one per capture PC (``[[sensors]] host``, default the sensor id)
    app-<name>.pem, .key                   one per app (``--app NAME``): subscribe / query only

Keys are ECDSA P-256, PKCS#8 PEM, written with mode 0600. Certificates carry the identity's common name
(:func:`skelfuse.config.access.common_name`, what the router's access control matches), serverAuth and
clientAuth usages (every process both listens and connects), and the DNS names / IP addresses given
(``--san``) for clients that verify names. An existing CA is reused, so certificates can be added later.
"""

from __future__ import annotations

import datetime
import ipaddress
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from skelfuse.config.access import common_name
from skelfuse.schema.errors import ConfigError

log = logging.getLogger("skelfuse.service.certs")

CA_NAME = "ca"


@dataclass(frozen=True)
class IssuedCertificate:
    identity: str
    common_name: str
    certificate: Path
    private_key: Path
    not_after: datetime.datetime


def _write_private(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as handle:
        handle.write(data)


def _new_key() -> Any:
    from cryptography.hazmat.primitives.asymmetric import ec

    return ec.generate_private_key(ec.SECP256R1())


def _key_pem(key: Any) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


def load_or_make_ca(directory: Path, rig: str, *, days: int, now: datetime.datetime) -> tuple[Any, Any]:
    """The rig's CA certificate and key in ``directory`` (made when absent)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.x509.oid import NameOID

    cert_path, key_path = directory / f"{CA_NAME}.pem", directory / f"{CA_NAME}.key"
    if cert_path.exists() and key_path.exists():
        ca_cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
        ca_key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
        expected = f"{rig}.skelfuse CA"
        found = ca_cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value
        if found != expected:
            raise ConfigError(f"{cert_path} is the CA of {found!r}, not of rig {rig!r}; use another --output")
        return ca_cert, ca_key
    if cert_path.exists() != key_path.exists():
        raise ConfigError(f"{directory} holds only one of ca.pem / ca.key; restore the other or use a new --output")
    key = _new_key()
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"{rig}.skelfuse CA")])
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
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
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    _write_private(key_path, _key_pem(key))
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    log.info("made the CA of rig %s: %s", rig, cert_path)
    return cert, key


def issue(
    directory: Path,
    rig: str,
    identity: str,
    ca: tuple[Any, Any],
    *,
    sans: Sequence[str] = (),
    days: int,
    now: datetime.datetime,
) -> IssuedCertificate:
    """Write ``<identity>.pem`` / ``.key`` signed by the CA (replacing an older pair)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    ca_cert, ca_key = ca
    key = _new_key()
    cn = common_name(rig, identity)
    names: list[x509.GeneralName] = [x509.DNSName(cn), x509.DNSName("localhost")]
    for san in sans:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(san)))
        except ValueError:
            names.append(x509.DNSName(san))
    not_after = now + datetime.timedelta(days=days)
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)]))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(not_after)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=False,
                crl_sign=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False
        )
        .add_extension(x509.SubjectAlternativeName(names), critical=False)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    cert_path, key_path = directory / f"{identity}.pem", directory / f"{identity}.key"
    _write_private(key_path, _key_pem(key))
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return IssuedCertificate(identity, cn, cert_path, key_path, not_after)


def make_rig_certificates(
    directory: Path,
    rig: str,
    identities: Sequence[str],
    *,
    sans: Sequence[str] = (),
    days: int = 825,
    now: datetime.datetime | None = None,
) -> list[IssuedCertificate]:
    """The CA (made or reused) and one certificate per identity in ``directory``."""
    try:
        import cryptography  # noqa: F401
    except ImportError:  # pragma: no cover - a dependency; only a broken install gets here
        raise ConfigError("skelfuse certs needs the cryptography package: pip install cryptography") from None
    now = now or datetime.datetime.now(datetime.UTC)
    directory.mkdir(parents=True, exist_ok=True)
    ca = load_or_make_ca(directory, rig, days=days, now=now)
    issued = []
    for identity in identities:
        issued.append(issue(directory, rig, identity, ca, sans=sans, days=days, now=now))
        log.info("certificate %s (CN %s)", issued[-1].certificate, issued[-1].common_name)
    return issued
