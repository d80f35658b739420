"""The one way the bus parses its JSON payloads (status, footprint, frames, mission) and
checks their schema, version and fields.

Parsing is strict: JSON has no NaN or infinity, so ``NaN``, ``Infinity`` and ``-Infinity``
(which Python's json accepts) and numbers too large for a float (``1e400``) are refused,
naming where they are, and a decoded document holds only finite numbers. ``Fields`` reads
one object's fields with their types and ranges, each refusal naming the field.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from typing import Any

from pdcov.bus.errors import BusPayloadError, Refusal, Refuser
from pdcov.ids import VEHICLE_ID_RULE, valid_vehicle_id

_MISSING = object()  # a key absent from the payload (None is JSON null)


def json_object(payload: bytes, max_bytes: int, bad: Refuser) -> dict[str, Any]:
    """The JSON object in ``payload``; raises ``bad(why)`` when it is longer than
    ``max_bytes``, not UTF-8 JSON (nested too deep for the parser included: a hostile
    ``[[[[…`` raises RecursionError in json), holds a non-finite number or is not an
    object."""
    data = bytes(payload)
    if len(data) > max_bytes:
        raise bad(f"{len(data)} bytes, more than {max_bytes}", Refusal.TOO_LARGE)
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        # ValueError: json.JSONDecodeError, and an integer of more than 4300 digits
        raise bad(f"not UTF-8 JSON ({str(exc)[:100]})", Refusal.MALFORMED) from None
    if not isinstance(doc, dict):
        raise bad("expected a JSON object", Refusal.MALFORMED)
    where = _non_finite_at(doc)
    if where is not None:
        raise bad(f"{where}: a non-finite number (NaN, Infinity or beyond a float; JSON "
                  "has none)", Refusal.NON_FINITE)
    return doc


def _non_finite_at(doc: Any) -> str | None:
    """The path ("grid.x0_m", "thresholds[2]") of the first non-finite number in a parsed
    document (json reads NaN, Infinity and 1e400 as floats), or None. Iterative: the
    parser's own recursion limit already bounds the depth."""
    stack: list[tuple[str, Any]] = [("", doc)]
    while stack:
        path, v = stack.pop()
        if isinstance(v, float) and not math.isfinite(v):
            return path or "payload"
        if isinstance(v, dict):
            stack += ((f"{path}.{k}" if path else str(k), x) for k, x in v.items())
        elif isinstance(v, list):
            stack += ((f"{path}[{i}]", x) for i, x in enumerate(v))
    return None


def check_schema(holder: Mapping[str, Any], schema: str, version: int | tuple[int, ...],
                 bad: Refuser, where: str = "") -> int:
    """Raise ``bad(why)`` unless ``holder["schema"] == schema`` and ``holder["version"]`` is
    the integer ``version`` (or one of them; JSON ``true`` or ``1.0`` is not version 1);
    returns the version. ``holder`` is the object that carries the two keys: the payload
    itself, or the footprint's GeoJSON ``properties`` (``where`` "properties." then names
    them in the message)."""
    got = holder.get("schema", _MISSING)
    if got != schema:
        raise bad(f"{where}schema {_shown(got)}, expected {schema!r}", Refusal.MALFORMED)
    versions = (version,) if isinstance(version, int) else version
    got = holder.get("version", _MISSING)
    if type(got) is not int or got not in versions:
        expected = (f"{version} (the only version this receiver reads)"
                    if isinstance(version, int)
                    else f"one of {', '.join(map(str, versions))} (the versions this "
                    "receiver reads)")
        raise bad(f"{where}version {_shown(got)}, expected {expected}", Refusal.MALFORMED)
    return got


def is_number(v: Any) -> bool:
    """A finite JSON number (not ``true``/``false``, which Python counts as ints)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def is_integer(v: Any) -> bool:
    """A JSON integer (``1.0`` and ``true`` are not)."""
    return isinstance(v, int) and not isinstance(v, bool)


def finite_or_null(v: Any) -> Any:
    """``v`` with every non-finite float (NaN, ±inf) in it replaced by None, mappings' keys
    made strings: what json.dumps(allow_nan=False) then writes as strict JSON."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, Mapping):
        return {str(k): finite_or_null(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [finite_or_null(x) for x in v]
    return v


class Fields:
    """Typed reads of one JSON object's fields. Each method raises ``bad`` naming the field
    (``where`` + its name: "grid.n_rows") and what was expected; ``*_or_null`` ones accept
    null (and an absent field) as None."""

    def __init__(self, doc: Any, bad: Refuser, where: str = "") -> None:
        if not isinstance(doc, dict):
            raise bad(f"{where.rstrip('.') or 'payload'}: expected an object, got "
                      f"{_kind(doc)}")
        self.doc: dict[str, Any] = doc
        self.bad = bad
        self.where = where

    def _fail(self, name: str, expected: str) -> BusPayloadError:
        got = self.doc.get(name, _MISSING)
        return self.bad(f"{self.where}{name}: expected {expected}, got {_shown(got)}")

    def obj(self, name: str) -> Fields:
        """The object field ``name``, to read its own fields."""
        v = self.doc.get(name)
        if not isinstance(v, dict):
            raise self._fail(name, "an object")
        return Fields(v, self.bad, f"{self.where}{name}.")

    def obj_or_null(self, name: str) -> Fields | None:
        return None if self.doc.get(name) is None else self.obj(name)

    def number(self, name: str, lo: float = -math.inf, hi: float = math.inf) -> float:
        """A finite number in [lo, hi]."""
        v: Any = self.doc.get(name)
        if not (is_number(v) and lo <= v <= hi):
            raise self._fail(name, f"a number in [{lo:g}, {hi:g}]")
        return float(v)

    def number_or_null(self, name: str, lo: float = -math.inf, hi: float = math.inf
                       ) -> float | None:
        return None if self.doc.get(name) is None else self.number(name, lo, hi)

    def integer(self, name: str, lo: int, hi: int) -> int:
        """An integer in [lo, hi]."""
        v: Any = self.doc.get(name)
        if not (is_integer(v) and lo <= v <= hi):
            raise self._fail(name, f"an integer in [{lo}, {hi}]")
        return int(v)

    def integer_or_null(self, name: str, lo: int, hi: int) -> int | None:
        return None if self.doc.get(name) is None else self.integer(name, lo, hi)

    def string(self, name: str, pattern: re.Pattern[str] | None = None,
               max_len: int = 200) -> str:
        """A string of at most ``max_len`` characters (matching ``pattern`` whole)."""
        v = self.doc.get(name)
        if not (isinstance(v, str) and len(v) <= max_len
                and (pattern is None or pattern.fullmatch(v))):
            what = f"a string of at most {max_len} characters"
            raise self._fail(name, what if pattern is None else f"{what} matching "
                             f"{pattern.pattern!r}")
        return v

    def vehicle_id(self, name: str, key_vehicle_id: str | None = None) -> str:
        """A vehicle id (pdcov.ids.VEHICLE_ID_RULE); with ``key_vehicle_id`` (the one in the
        payload's key), that one."""
        vid = self.string(name, max_len=64)
        if not valid_vehicle_id(vid):
            raise self.bad(f"{self.where}{name}: {vid!r}, expected {VEHICLE_ID_RULE}")
        if key_vehicle_id is not None and vid != key_vehicle_id:
            raise self.bad(f"{self.where}{name} {vid!r}, but the key is vehicle "
                           f"{key_vehicle_id!r}'s")
        return vid

    def string_or_null(self, name: str, max_len: int = 200) -> str | None:
        return None if self.doc.get(name) is None else self.string(name, max_len=max_len)

    def boolean_or_null(self, name: str) -> bool | None:
        v = self.doc.get(name)
        if v is not None and not isinstance(v, bool):
            raise self._fail(name, "true, false or null")
        return v

    def items(self, name: str, most: int) -> list[Any]:
        """A list of at most ``most`` items (more: Refusal.OVER_BOUND)."""
        v = self.doc.get(name)
        if not isinstance(v, list):
            raise self._fail(name, "a list")
        if len(v) > most:
            raise self.bad(f"{self.where}{name}: {len(v)} items, more than {most}",
                           Refusal.OVER_BOUND)
        return v

    def counts(self, name: str, most: int, hi: int) -> dict[str, int]:
        """An object of at most ``most`` counts {name: integer in [0, hi]}."""
        sub = self.obj(name)
        if len(sub.doc) > most:
            raise self.bad(f"{self.where}{name}: {len(sub.doc)} entries, more than {most}",
                           Refusal.OVER_BOUND)
        return {k: sub.integer(k, 0, hi) for k in sub.doc}


def _kind(v: Any) -> str:
    return "null" if v is None else {dict: "an object", list: "a list", str: "a string",
                                     bool: "a boolean"}.get(type(v), "a number")


def _shown(value: Any) -> str:
    """A received value for a message: "missing", or its repr cut to 60 characters."""
    if value is _MISSING:
        return "missing"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
