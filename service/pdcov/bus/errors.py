"""Errors of the bus: a payload that does not decode names the key and the fault."""

from __future__ import annotations

from pdcov.errors import PdcovError


class BusPayloadError(PdcovError):
    """A payload received over Zenoh is malformed, of another schema version, or does not
    fit the grid it is meant for; nothing was applied."""
