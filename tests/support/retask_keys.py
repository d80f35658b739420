"""An operator key for the re-tasking tests, and signed requests made with it."""

from __future__ import annotations

import itertools
from pathlib import Path

from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from pdcov.bus.operator_keys import OperatorKey
from pdcov.bus.retask import encode_signed_retask

KEY = OperatorKey.of(Ed25519PrivateKey.generate())
OTHER = OperatorKey.of(Ed25519PrivateKey.generate())  # a key no vehicle lists
UNIX_S = 1_780_000_000.0
"""The tests' UTC clock, s."""
_nonces = itertools.count()


def write_pub(folder: Path, key: OperatorKey = KEY) -> Path:
    """``key``'s public half as operator.pub in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "operator.pub"
    path.write_bytes(key.key.public_key().public_bytes(
        serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo))
    return path


def write_key(folder: Path, key: OperatorKey = KEY) -> Path:
    """``key`` as operator.key in ``folder`` (as `pdcov keys new` writes it)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "operator.key"
    path.write_bytes(key.key.private_bytes(serialization.Encoding.PEM,
                                           serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
    path.chmod(0o600)
    return path


def signed(items, vehicle_id: str = "fuzz", unix_s: float = UNIX_S, nonce: str | None = None,
           key: OperatorKey = KEY, description: str = "") -> bytes:
    """A request signed by ``key`` with a fresh nonce (unless given)."""
    return encode_signed_retask(key, vehicle_id, items, description, unix_s,
                                nonce or f"{next(_nonces):032x}")
