"""The one way the bus parses its JSON payloads (status, footprint, frames, mission)."""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from pdcov.bus.errors import BusPayloadError


def json_object(payload: bytes, max_bytes: int,
                bad: Callable[[str], BusPayloadError]) -> dict[str, Any]:
    """The JSON object in ``payload``; raises ``bad(why)`` when it is longer than
    ``max_bytes``, not UTF-8 JSON (nested too deep for the parser included: a hostile
    ``[[[[…`` raises RecursionError in json) or not an object."""
    data = bytes(payload)
    if len(data) > max_bytes:
        raise bad(f"{len(data)} bytes, more than {max_bytes}")
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise bad(f"not UTF-8 JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise bad("expected a JSON object")
    return doc
