"""Errors of the bus: a payload that does not decode names the key and the fault, and says
in one word-group why (``Refusal``) so that a receiver can count refusals per reason."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from pdcov.errors import PdcovError


class Refusal(str, Enum):
    """Why a payload was refused (docs/protocol.md "Validation and bounds")."""

    TOO_LARGE = "too large"
    """More bytes than the kind's bound (MAX_*_BYTES)."""
    OVER_BOUND = "over a bound"
    """A count beyond a receiver's bound: cells per grid, thresholds, tiles, vertices."""
    MALFORMED = "malformed"
    """Not JSON, not a zip or tiles message, another schema or version."""
    NON_FINITE = "non-finite number"
    """NaN or an infinity where JSON and the protocol have none."""
    BAD_FIELD = "bad field"
    """A field missing, of the wrong type or out of its range."""
    OTHER_GRID = "another grid"
    """Tiles for a grid other than the one held."""
    OUTSIDE_PICTURE = "outside the picture"
    """A detector box not inside the camera's picture (frames version 2)."""


class BusPayloadError(PdcovError):
    """A payload received over Zenoh is malformed, of another schema version, or does not
    fit the grid it is meant for; nothing was applied. ``reason``: why, for counting."""

    def __init__(self, message: str, reason: Refusal = Refusal.BAD_FIELD) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True, slots=True)
class Refuser:
    """Builds a decoder's errors: ``bad(why, reason)`` -> BusPayloadError("<prefix>: why")."""

    prefix: str

    def __call__(self, why: str, reason: Refusal = Refusal.BAD_FIELD) -> BusPayloadError:
        return BusPayloadError(f"{self.prefix}: {why}", reason)
