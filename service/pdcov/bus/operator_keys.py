"""Operator keys: who may re-task a vehicle (docs/protocol.md "retask").

An operator key is an Ed25519 key pair (RFC 8032, the ``cryptography`` package): the
private key signs re-tasking requests at the ground station (``operator.key``, PEM PKCS#8,
mode 0600), the public key is listed in the vehicle's mission (``operator.pub``, PEM
SubjectPublicKeyInfo; ``service.retask_operator_keys``). A key is named by its key id: the
first 16 hex digits of the SHA-256 of the 32 raw public-key bytes.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from pdcov.errors import ConfigError

PRIVATE_NAME = "operator.key"
PUBLIC_NAME = "operator.pub"
MAX_KEY_FILE_BYTES = 4096


def key_id(public: Ed25519PublicKey) -> str:
    """The key's id: SHA-256 of its 32 raw bytes, first 16 hex digits."""
    raw = public.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return hashlib.sha256(raw).hexdigest()[:16]


@dataclass(frozen=True, slots=True)
class OperatorPublicKey:
    """A public key the vehicle obeys, with its id."""

    id: str
    key: Ed25519PublicKey

    @classmethod
    def of(cls, key: Ed25519PublicKey) -> OperatorPublicKey:
        return cls(key_id(key), key)

    def verifies(self, signature: bytes, data: bytes) -> bool:
        try:
            self.key.verify(signature, data)
        except InvalidSignature:
            return False
        return True


@dataclass(frozen=True, slots=True)
class OperatorKey:
    """An operator's private key (signs), with its public half's id."""

    id: str
    key: Ed25519PrivateKey

    @classmethod
    def of(cls, key: Ed25519PrivateKey) -> OperatorKey:
        return cls(key_id(key.public_key()), key)

    def sign(self, data: bytes) -> bytes:
        """The 64-byte Ed25519 signature of ``data``."""
        return self.key.sign(data)


def _read(path: Path, what: str) -> bytes:
    try:
        with path.open("rb") as f:
            data = f.read(MAX_KEY_FILE_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"{what} {path}: cannot read it ({exc.strerror})") from None
    if len(data) > MAX_KEY_FILE_BYTES:
        raise ConfigError(f"{what} {path}: larger than {MAX_KEY_FILE_BYTES} bytes: not a key")
    return data


def load_public_key(path: Path, what: str = "operator key") -> OperatorPublicKey:
    """An Ed25519 public key from a PEM file (``pdcov keys new``'s operator.pub);
    ConfigError naming ``what`` and the file otherwise."""
    try:
        key = serialization.load_pem_public_key(_read(path, what))
    except ValueError:
        raise ConfigError(f"{what} {path}: not a PEM public key (expected the operator.pub "
                          "`pdcov keys new` writes)") from None
    if not isinstance(key, Ed25519PublicKey):
        raise ConfigError(f"{what} {path}: not an Ed25519 key")
    return OperatorPublicKey.of(key)


def load_private_key(path: Path, what: str = "--operator-key") -> OperatorKey:
    """An Ed25519 private key from a PEM file (``pdcov keys new``'s operator.key);
    ConfigError naming ``what`` and the file otherwise."""
    try:
        key = serialization.load_pem_private_key(_read(path, what), password=None)
    except (ValueError, TypeError):
        raise ConfigError(f"{what} {path}: not an unencrypted PEM private key (expected the "
                          "operator.key `pdcov keys new` writes)") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise ConfigError(f"{what} {path}: not an Ed25519 key")
    return OperatorKey.of(key)


def write_key_pair(folder: Path) -> OperatorKey:
    """A new key pair in ``folder`` (created): operator.key (mode 0600) and operator.pub.
    ConfigError, writing nothing, when either file exists."""
    private, public = folder / PRIVATE_NAME, folder / PUBLIC_NAME
    for path in (private, public):
        if path.exists():
            raise ConfigError(f"{path}: exists; not overwritten (a key lost is a vehicle "
                              "that no longer obeys: move it away first)")
    key = Ed25519PrivateKey.generate()
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                            serialization.NoEncryption())
    pub = key.public_key().public_bytes(serialization.Encoding.PEM,
                                        serialization.PublicFormat.SubjectPublicKeyInfo)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(private, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(pem)
        with public.open("xb") as f:
            f.write(pub)
    except OSError as exc:
        raise ConfigError(f"{folder}: cannot write the key pair ({exc})") from None
    return OperatorKey.of(key)
