"""Mutual TLS for ``pdcov watch --cot tls://HOST:PORT``, a TAK server's TLS input (8089):
the client certificate and key the server issued, and its CA, checked before the watcher
starts and turned into pytak's settings (ground/cot_feed.py connects with them).

Each file is checked once, up front, and a failure is one ConfigError naming the option and
the file: missing or unreadable, not a certificate (PEM or PKCS#12), a key that is not the
certificate's, a wrong or missing password, a certificate not yet valid or expired, a CA
file without a certificate. Last, pytak builds the TLS context it will connect with, so
that what OpenSSL refuses is refused here too.

The server is always verified: against ``--cot-ca`` (a TAK server's CA is its own; pytak's
context trusts nothing else), its certificate's name against the URL's host, or against
``--cot-server-name`` when the certificate carries another name than the one dialled. There
is no option to skip either check: the feed carries the aircraft's positions and the
casualties' candidates, and a TAK server's admin hands out its CA with the client
certificate.

The identity OpenSSL loads is the one checked: certificate chain and key, the key encrypted
with a password made for this process, are written once into an anonymous in-memory file
(memfd, Linux), whose /proc/self/fd path pytak opens at each connection. The decrypted key
never touches the disk (pytak's own PKCS#12 support writes it to /tmp at each connection),
and a password with ``%`` in it never meets pytak's ConfigParser.
"""

from __future__ import annotations

import datetime as dt
import os
import re
import secrets
import ssl
from configparser import ConfigParser
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pdcov.errors import ConfigError
from pdcov.ground.secret_file import read_secret_file

__all__ = ["CotTls", "CotTlsFiles", "cot_tls_of"]

CIPHERS_TLS12 = "ECDH+AESGCM:ECDH+CHACHA20:ECDH+AES:DHE+AES:!aNULL:!eNULL:!aDSS:!SHA1:!AESCCM"
"""TLS 1.2 cipher suites offered (1.3's are all strong): those of Python's
``ssl.create_default_context()``. pytak's default, OpenSSL's ``ALL``, includes anonymous
suites (ADH) that authenticate no server."""

REFUSED_CERT = ("TLSV13_ALERT_CERTIFICATE_REQUIRED", "SSLV3_ALERT_BAD_CERTIFICATE",
                "TLSV1_ALERT_UNKNOWN_CA", "SSLV3_ALERT_CERTIFICATE_UNKNOWN",
                "SSLV3_ALERT_CERTIFICATE_EXPIRED", "SSLV3_ALERT_CERTIFICATE_REVOKED",
                "SSLV3_ALERT_UNSUPPORTED_CERTIFICATE", "TLSV1_ALERT_ACCESS_DENIED")
"""The alerts with which a server refuses the client's certificate (OpenSSL's reasons)."""

_PEM = re.compile(rb"-----BEGIN ([A-Z0-9 ]+)-----.+?-----END \1-----\r?\n?", re.DOTALL)

FLAGS = {"cert": "--cot-cert", "key": "--cot-key",
         "key_password_file": "--cot-key-password-file", "ca": "--cot-ca",
         "server_name": "--cot-server-name"}


@dataclass(frozen=True, slots=True)
class CotTlsFiles:
    """What the ``--cot-*`` TLS options name (None: not given)."""

    cert: Path | None = None
    key: Path | None = None
    key_password_file: Path | None = None
    ca: Path | None = None
    server_name: str | None = None


@dataclass(frozen=True, slots=True)
class CotTls:
    """A checked client identity: ``identity_fd`` the memfd holding the PEM chain and key,
    the key encrypted with ``identity_password``; the CA that verifies the server, the name
    its certificate must carry (None: the URL's host), and for messages the certificate's
    file and subject. ``close`` when done."""

    identity_fd: int
    identity_password: str = field(repr=False)
    ca: Path
    server_name: str | None
    cert: Path
    subject: str

    @property
    def identity_path(self) -> str:
        return f"/proc/self/fd/{self.identity_fd}"

    def close(self) -> None:
        os.close(self.identity_fd)

    def pytak_settings(self) -> dict[str, str]:
        """pytak's configuration keys for this identity (pytak client_functions
        ``get_ssl_ctx``, ``create_tls_client``)."""
        out = {"PYTAK_TLS_CLIENT_CERT": self.identity_path,
               "PYTAK_TLS_CLIENT_KEY": self.identity_path,  # the same file: pytak wants both
               "PYTAK_TLS_CLIENT_PASSWORD": self.identity_password,
               "PYTAK_TLS_CLIENT_CAFILE": str(self.ca),
               "PYTAK_TLS_CLIENT_CIPHERS": CIPHERS_TLS12}
        if self.server_name is not None:
            out["PYTAK_TLS_SERVER_EXPECTED_HOSTNAME"] = self.server_name
        return out

    def explain(self, exc: BaseException, just_connected: bool = False) -> str:
        """A connection's failure in the operator's terms: the server's certificate not
        verified by --cot-ca, or the client certificate refused by the server: said so by
        its alert, or likely when the server ends a connection ``just_connected`` (a TLS
        1.3 server checks the client's certificate after the client's handshake ends, and
        some close without an alert)."""
        cause = exc.__cause__ if isinstance(exc, SyntaxError) else exc  # pytak's wrapping
        if isinstance(cause, ssl.SSLCertVerificationError):
            hint = "" if "mismatch" not in str(cause.verify_message).lower() else \
                " (--cot-server-name NAME: the name its certificate carries)"
            return (f"the server's certificate does not verify against --cot-ca {self.ca}: "
                    f"{cause.verify_message}{hint}")
        refused = f"the client certificate --cot-cert {self.cert} ({self.subject})"
        if isinstance(cause, ssl.SSLError) and cause.reason in REFUSED_CERT:
            return f"the server refused {refused}: {cause.reason}"
        if just_connected and isinstance(cause, (ConnectionError, ssl.SSLEOFError)):
            return (f"the server ended the connection right after the handshake ({exc}): "
                    f"most likely it refused {refused}, signed by a CA it does not trust, "
                    "revoked or expired")
        return str(exc) or type(exc).__name__


def cot_tls_of(url: str | None, files: CotTlsFiles, now_unix_s: float) -> CotTls | None:
    """The checked identity for ``--cot url`` (module docstring), None without --cot or
    for udp:// and tcp://; ConfigError naming the option and file for what is wrong, and
    for TLS options given without tls://, or tls:// without --cot-cert and --cot-ca."""
    given = [FLAGS[k] for k in FLAGS if getattr(files, k) is not None]
    if url is None or not url.startswith("tls://"):
        if given:
            raise ConfigError(f"{', '.join(given)}: only with --cot tls://HOST:PORT (a TAK "
                              "server's TLS input), not "
                              + ("without --cot" if url is None else f"--cot {url}"))
        return None
    if files.cert is None or files.ca is None:
        raise ConfigError(f"--cot {url}: needs --cot-cert (the client certificate the TAK "
                          "server issued, PEM or .p12) and --cot-ca (its CA, PEM), "
                          "docs/ground-station.md \"Cursor-on-Target over TLS\"")
    if files.server_name is not None and not files.server_name.strip():
        raise ConfigError("--cot-server-name: expected the host name the server's "
                          "certificate carries, got an empty one")
    password = None
    if files.key_password_file is not None:
        password = read_secret_file(files.key_password_file, "--cot-key-password-file") \
            .rstrip("\r\n").encode()
    chain, key = _identity(files.cert, files.key, password)
    now = dt.datetime.fromtimestamp(now_unix_s, dt.timezone.utc)
    _check_valid(chain[0], "--cot-cert", files.cert, now)
    ca_certs = _certificates(_read(files.ca, "--cot-ca"), "--cot-ca", files.ca)
    if all(c.not_valid_after_utc < now for c in ca_certs):
        raise ConfigError(f"--cot-ca {files.ca}: expired on "
                          f"{_day(min(c.not_valid_after_utc for c in ca_certs))}")
    tls = _in_memory(chain, key, files.cert, files.ca, files.server_name)
    try:
        _check_with_pytak(tls)
    except ConfigError:
        tls.close()
        raise
    return tls


def _read(path: Path, flag: str) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{flag} {path}: cannot read it ({exc.strerror})") from None


def _certificates(data: bytes, flag: str, path: Path) -> list[Any]:
    from cryptography import x509

    blocks = [m.group(0) for m in _PEM.finditer(data) if m.group(1) == b"CERTIFICATE"]
    if not blocks:
        raise ConfigError(f"{flag} {path}: no PEM certificate in it (-----BEGIN "
                          "CERTIFICATE-----)")
    try:
        return [x509.load_pem_x509_certificate(b) for b in blocks]
    except ValueError as exc:
        raise ConfigError(f"{flag} {path}: not a readable certificate ({exc})") from None


def _identity(cert: Path, key_file: Path | None, password: bytes | None
              ) -> tuple[list[Any], Any]:
    """(certificate chain, leaf first; private key) from --cot-cert and --cot-key."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.serialization import pkcs12

    data = _read(cert, "--cot-cert")
    if b"-----BEGIN" not in data:  # DER: a PKCS#12 file, as TAK servers hand them out
        if key_file is not None:
            raise ConfigError(f"--cot-key {key_file}: not with a PKCS#12 --cot-cert "
                              f"{cert}, which holds the key")
        try:
            key, leaf, more = pkcs12.load_key_and_certificates(data, password)
        except ValueError:
            raise ConfigError(
                f"--cot-cert {cert}: neither PEM nor a PKCS#12 file "
                + ("that --cot-key-password-file opens (wrong password?)" if password
                   else "without a password (give --cot-key-password-file)")) from None
        if key is None or leaf is None:
            raise ConfigError(f"--cot-cert {cert}: the PKCS#12 file holds no "
                              f"{'key' if key is None else 'certificate'}")
        return [leaf, *more], key
    chain = _certificates(data, "--cot-cert", cert)
    flag, source = ("--cot-key", key_file) if key_file is not None else ("--cot-cert", cert)
    text = data if key_file is None else _read(key_file, "--cot-key")
    blocks = [m.group(0) for m in _PEM.finditer(text) if b"PRIVATE KEY" in m.group(1)]
    if not blocks:
        raise ConfigError(f"{flag} {source}: no PEM private key in it"
                          + ("" if key_file else " (give --cot-key)"))
    try:
        key = serialization.load_pem_private_key(blocks[0], password)
    except TypeError:  # a password for a plain key, or none for an encrypted one
        raise ConfigError(f"{flag} {source}: " + (
            "not encrypted: drop --cot-key-password-file" if password else
            "encrypted: give its password with --cot-key-password-file")) from None
    except ValueError:
        raise ConfigError(f"{flag} {source}: cannot be read"
                          + (" with the password of --cot-key-password-file (wrong "
                             "password?)" if password else "")) from None
    if key.public_key() != chain[0].public_key():
        raise ConfigError(f"{flag} {source}: not the key of --cot-cert {cert} "
                          f"({chain[0].subject.rfc4514_string()})")
    return chain, key


def _day(t: dt.datetime) -> str:
    return t.strftime("%Y-%m-%d %H:%M UTC")


def _check_valid(cert: Any, flag: str, path: Path, now: dt.datetime) -> None:
    if cert.not_valid_after_utc < now:
        raise ConfigError(f"{flag} {path}: {cert.subject.rfc4514_string()} expired on "
                          f"{_day(cert.not_valid_after_utc)} (ask the TAK server's admin "
                          "for a new one)")
    if cert.not_valid_before_utc > now:
        raise ConfigError(f"{flag} {path}: {cert.subject.rfc4514_string()} is valid only "
                          f"from {_day(cert.not_valid_before_utc)} (is this clock right?)")


def _in_memory(chain: list[Any], key: Any, cert: Path, ca: Path, server_name: str | None
               ) -> CotTls:
    """The identity written to a memfd (module docstring), kept open while we run."""
    from cryptography.hazmat.primitives import serialization

    if not hasattr(os, "memfd_create"):
        raise ConfigError("--cot tls://: needs Linux (an in-memory file holds the client "
                          "identity)")
    password = secrets.token_hex(32)
    pem = b"".join(c.public_bytes(serialization.Encoding.PEM) for c in chain) + \
        key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                          serialization.BestAvailableEncryption(password.encode()))
    fd = os.memfd_create("pdcov-cot-identity", os.MFD_CLOEXEC)
    with open(fd, "wb", closefd=False) as f:
        f.write(pem)
    return CotTls(fd, password, ca, server_name, cert, chain[0].subject.rfc4514_string())


def _check_with_pytak(tls: CotTls) -> None:
    """pytak builds the context it will connect with: what OpenSSL refuses (a CA file it
    cannot load, a key type it lacks) is refused now, not at the first connection."""
    from pytak.client_functions import get_ssl_ctx

    config = ConfigParser(interpolation=None)
    config["tls"] = tls.pytak_settings()
    try:
        get_ssl_ctx(config["tls"])
    except ValueError as exc:  # pytak: "Error opening resource" from load_cert_chain
        raise ConfigError(f"--cot-cert {tls.cert}: OpenSSL cannot use it "
                          f"({exc.__cause__ or exc})") from None
    except ssl.SSLError as exc:  # load_verify_locations
        raise ConfigError(f"--cot-ca {tls.ca}: OpenSSL cannot use it ({exc})") from None
