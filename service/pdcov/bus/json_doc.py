"""The one way the bus parses its JSON payloads (status, footprint, frames, mission) and
checks their schema and version."""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from typing import Any

from pdcov.bus.errors import BusPayloadError

_MISSING = object()  # a key absent from the payload (None is JSON null)


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


def check_schema(holder: Mapping[str, Any], schema: str, version: int,
                 bad: Callable[[str], BusPayloadError], where: str = "") -> None:
    """Raise ``bad(why)`` unless ``holder["schema"] == schema`` and ``holder["version"]`` is
    the integer ``version`` (JSON ``true`` or ``1.0`` is not version 1). ``holder`` is the
    object that carries the two keys: the payload itself, or the footprint's GeoJSON
    ``properties`` (``where`` "properties." then names them in the message)."""
    got = holder.get("schema", _MISSING)
    if got != schema:
        raise bad(f"{where}schema {_shown(got)}, expected {schema!r}")
    got = holder.get("version", _MISSING)
    if type(got) is not int or got != version:
        raise bad(f"{where}version {_shown(got)}, expected {version} (the only version this "
                  "receiver reads)")


def _shown(value: Any) -> str:
    """A received value for a message: "missing", or its repr cut to 60 characters."""
    if value is _MISSING:
        return "missing"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
