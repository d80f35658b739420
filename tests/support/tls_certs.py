"""Certificates for the Zenoh TLS tests, made here with the ``cryptography`` package: a
certificate authority and leaf certificates signed by it (key and certificate as PEM
files, the key encrypted when asked; or one PKCS#12 file), valid for localhost and
127.0.0.1."""

from __future__ import annotations

import datetime as dt
import ipaddress
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.serialization import pkcs12
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID


@dataclass(frozen=True, slots=True)
class Leaf:
    """A leaf certificate's files and its common name."""

    common_name: str
    key: Path
    cert: Path


class Authority:
    """A self-signed CA in ``folder`` (ca.pem); ``leaf(cn)`` issues a certificate."""

    def __init__(self, folder: Path, name: str = "pdcov test CA") -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self._key = ec.generate_private_key(ec.SECP256R1())
        self._name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
        now = dt.datetime.now(dt.timezone.utc)
        self._cert = (
            x509.CertificateBuilder().subject_name(self._name).issuer_name(self._name)
            .public_key(self._key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=2))
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True,
                                         crl_sign=True, content_commitment=False,
                                         key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False,
                                         decipher_only=False), critical=True)
            .sign(self._key, hashes.SHA256()))
        self.ca = self.folder / "ca.pem"
        self.ca.write_bytes(self._cert.public_bytes(serialization.Encoding.PEM))

    def leaf(self, common_name: str, *, key_password: bytes | None = None,
             expired: bool = False) -> Leaf:
        """Key and certificate for ``common_name``, usable as TLS server and client; the
        key encrypted with ``key_password``; with ``expired``, one that ended an hour ago."""
        key = ec.generate_private_key(ec.SECP256R1())
        now = dt.datetime.now(dt.timezone.utc)
        end = now - dt.timedelta(hours=1) if expired else now + dt.timedelta(days=1)
        cert = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)]))
            .issuer_name(self._name).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(days=2))
            .not_valid_after(end)
            .add_extension(x509.SubjectAlternativeName([
                x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                critical=False)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                  ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .sign(self._key, hashes.SHA256()))
        out = Leaf(common_name, self.folder / f"{common_name}-key.pem",
                   self.folder / f"{common_name}.pem")
        out.key.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                              serialization.PrivateFormat.PKCS8,
                                              serialization.NoEncryption() if key_password is None
                                              else serialization.BestAvailableEncryption(
                                                  key_password)))
        out.cert.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        return out

    def p12(self, leaf: Leaf, password: bytes) -> Path:
        """``leaf``'s key and certificate, with this CA's, as a PKCS#12 file (what a TAK
        server hands out) encrypted with ``password``, beside the leaf's files."""
        key = serialization.load_pem_private_key(leaf.key.read_bytes(), password=None)
        cert = x509.load_pem_x509_certificate(leaf.cert.read_bytes())
        out = self.folder / f"{leaf.common_name}.p12"
        out.write_bytes(pkcs12.serialize_key_and_certificates(
            leaf.common_name.encode(), key, cert, [self._cert],  # type: ignore[arg-type]
            serialization.BestAvailableEncryption(password)))
        return out
