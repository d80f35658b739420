"""The identifiers pdcov checks, each in one place: vehicle ids (the mission config's
``vehicle_id``, the bus's key expressions, ``pdcov watch --vehicle``) and MAVLink system ids
(``log.system_id``, ``link.system_id``, ``pdcov-sitl fly --system-id``).

Both checks return a bool (a vehicle id that passes is a ``str`` to mypy); the caller
raises its own error (``ConfigError`` for a config file or an option, ``ValueError`` for a
value built in code, ``BusPayloadError`` for a payload), naming the key and the rule.
"""

from __future__ import annotations

import re
import secrets
from typing import TypeGuard

__all__ = ["EPOCH_RULE", "MAX_VEHICLE_ID_CHARS", "SYSTEM_IDS", "VEHICLE_ID_RULE",
           "candidate_uid_prefix", "new_epoch", "valid_epoch", "valid_system_id",
           "valid_vehicle_id"]

MAX_VEHICLE_ID_CHARS = 64
"""Longest vehicle id: it is in every key expression, status, file name and map label."""
VEHICLE_ID_RULE = f"ASCII letters, digits, - and _ (1..{MAX_VEHICLE_ID_CHARS} characters)"
"""What ``valid_vehicle_id`` accepts, for error messages."""

SYSTEM_IDS = range(1, 256)
"""MAVLink system ids a vehicle may have: 1..255. The header's sysid is one byte and 0 is
the broadcast address, invalid as a source (mavlink.io/en/guide/serialization.html, the
``sysid`` field; mavlink.io/en/guide/routing.html: "The system id has a value between 1 and
255"). Ground stations conventionally take 255, but that is a convention, not a reserved
value: an autopilot set to SYSID_THISMAV 255 is still followed."""


def valid_vehicle_id(vehicle_id: object) -> TypeGuard[str]:
    """A string of 1..MAX_VEHICLE_ID_CHARS ASCII letters, digits, '-' and '_': no Zenoh
    wildcard or separator can hide in it, and it is one key chunk on every bus."""
    return (isinstance(vehicle_id, str) and 0 < len(vehicle_id) <= MAX_VEHICLE_ID_CHARS
            and vehicle_id.isascii()
            and vehicle_id.replace("_", "").replace("-", "").isalnum())


def valid_system_id(system_id: object) -> bool:
    """An int (not a bool) in ``SYSTEM_IDS``."""
    return (isinstance(system_id, int) and not isinstance(system_id, bool)
            and system_id in SYSTEM_IDS)


EPOCH_RULE = "6 lowercase hexadecimal digits"
"""What ``valid_epoch`` accepts, for error messages."""
_EPOCH = re.compile(r"[0-9a-f]{6}")


def valid_epoch(epoch: object) -> TypeGuard[str]:
    """An epoch token (EPOCH_RULE): the daemon's state directory's (``STATE/epoch``) or a
    flight log's (the first 6 hex digits of its SHA-256), in every candidate uid."""
    return isinstance(epoch, str) and _EPOCH.fullmatch(epoch) is not None


def new_epoch() -> str:
    """A fresh random epoch token (24 bits)."""
    return secrets.token_hex(3)


def candidate_uid_prefix(vehicle_id: str, epoch: str) -> str:
    """``<vehicle_id>.<epoch>.``: a candidate's uid is this and its id, unique across
    vehicles (the id), restarts (the ids continue) and state directories or logs (the
    epoch); at most 64 + 8 + 20 characters."""
    if not valid_vehicle_id(vehicle_id) or not valid_epoch(epoch):
        raise ValueError(f"uid prefix of vehicle {vehicle_id!r}, epoch {epoch!r}: expected "
                         f"{VEHICLE_ID_RULE} and {EPOCH_RULE}")
    return f"{vehicle_id}.{epoch}."
