"""Certificates for authenticated links: a small certificate authority and one certificate per
station (and one for the operator's tools), each naming its holder in its common name, which
Zenoh's access control matches (`security.access`)."""

from __future__ import annotations

import datetime
import ipaddress
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from abyss.common.errors import ConfigError
from abyss.interface import keys

OPERATOR = "operator"  # the common name of the operator's tools (abyss op, link, check, health)
HOLDERS: tuple[str, ...] = (*keys.STATIONS, OPERATOR)
VALID_DAYS = 825


@dataclass(frozen=True)
class CertFiles:
    """Where one holder's certificate, key and the authority's certificate are."""

    directory: Path
    holder: str

    @property
    def ca(self) -> Path:
        return self.directory / "ca.pem"

    @property
    def certificate(self) -> Path:
        return self.directory / f"{self.holder}.pem"

    @property
    def private_key(self) -> Path:
        return self.directory / f"{self.holder}.key"

    def check(self) -> CertFiles:
        """Fail at start, naming the file, if one is missing."""
        for path in (self.ca, self.certificate, self.private_key):
            if not path.is_file():
                raise ConfigError(
                    "tls",
                    f"{path} is missing; make the certificates with `abyss certs make {self.directory}`",
                )
        return self


def _name(common_name: str) -> x509.Name:
    return x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, "abyss"),
            x509.NameAttribute(NameOID.COMMON_NAME, common_name),
        ]
    )


def _write_key(path: Path, key: ec.EllipticCurvePrivateKey) -> None:
    path.write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
    )
    path.chmod(0o600)


def make(directory: Path, hosts: dict[str, list[str]] | None = None) -> list[Path]:
    """Write `ca.pem`, `ca.key` and `<holder>.pem`/`.key` for every holder into `directory`.
    Each certificate serves both ends of a link (server and client authentication) and names
    its holder, `localhost` and 127.0.0.1, plus `hosts[holder]` (names or addresses), as
    subject alternative names."""
    directory.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.UTC)
    valid = (now - datetime.timedelta(minutes=5), now + datetime.timedelta(days=VALID_DAYS))
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_cert = _ca_certificate(ca_key, valid)
    written = [directory / "ca.pem", directory / "ca.key"]
    written[0].write_bytes(ca_cert.public_bytes(serialization.Encoding.PEM))
    _write_key(written[1], ca_key)
    for holder in HOLDERS:
        files = CertFiles(directory, holder)
        key = ec.generate_private_key(ec.SECP256R1())
        cert = _holder_certificate(holder, key, (hosts or {}).get(holder, []), ca_key, ca_cert, valid)
        files.certificate.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        _write_key(files.private_key, key)
        written += [files.certificate, files.private_key]
    return written


def _ca_certificate(
    ca_key: ec.EllipticCurvePrivateKey, valid: tuple[datetime.datetime, datetime.datetime]
) -> x509.Certificate:
    """The CA's own certificate: it signs certificates and nothing else."""
    return (
        x509.CertificateBuilder()
        .subject_name(_name("abyss CA"))
        .issuer_name(_name("abyss CA"))
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(valid[0])
        .not_valid_after(valid[1])
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                key_cert_sign=True,
                crl_sign=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .sign(ca_key, hashes.SHA256())
    )


def _alternative_names(holder: str, hosts: list[str]) -> list[x509.GeneralName]:
    """The holder, `localhost`, 127.0.0.1 and each of `hosts` (an address, else a name)."""
    names: list[x509.GeneralName] = [
        x509.DNSName(holder),
        x509.DNSName("localhost"),
        x509.IPAddress(ipaddress.ip_address("127.0.0.1")),
    ]
    for host in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    return names


def _holder_certificate(
    holder: str,
    key: ec.EllipticCurvePrivateKey,
    hosts: list[str],
    ca_key: ec.EllipticCurvePrivateKey,
    ca_cert: x509.Certificate,
    valid: tuple[datetime.datetime, datetime.datetime],
) -> x509.Certificate:
    """A holder's certificate, signed by the CA, for both ends of a link."""
    return (
        x509.CertificateBuilder()
        .subject_name(_name(holder))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(valid[0])
        .not_valid_after(valid[1])
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.SubjectAlternativeName(_alternative_names(holder, hosts)), critical=False)
        .add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
            critical=False,
        )
        .sign(ca_key, hashes.SHA256())
    )
