"""The status payload (``pdcov/<id>/status``, about 1 Hz): UTF-8 JSON, one object.

Fields (docs/protocol.md "status" gives each one's meaning and unit): schema, version,
vehicle_id, seq, uptime_s, t_s, thresholds, proportion_at_or_above, mean_pd,
expected_false_alarms, cells_free, cells_observed, frames {used, skipped {reason: n}},
link {...}, pose {lat_deg, lon_deg, alt_msl_m, heading_deg, t_s} or null, gimbal {...},
grid {hash, x0_m, y0_m, cell_size_m, n_rows, n_cols, tile_size, origin {lat_deg,
lon_deg, ground_alt_msl_m}}, tiles_seq, faults {name: n}, checkpoint {...}, full.

``StatusEncoder`` keeps the daemon's status under its 1 kB/s budget: the detail that rarely
changes (the link's negotiation, the gimbal's description, the checkpoint) goes out in
full statuses only -- the first, every ``FULL_EVERY``-th and any whose detail changed --
and the others carry the same required fields with a brief ``link`` and ``gimbal``.
``merge_status`` gives a receiver the latest values with the last full status's detail.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.json_doc import check_schema, json_object

STATUS_SCHEMA = "pdcov.status"
STATUS_VERSION = 1
MAX_STATUS_BYTES = 64 * 1024
FULL_EVERY = 20
"""Every this many statuses (20 s at 1 Hz) one is full even when no detail changed."""
BRIEF_LINK = ("state", "last_message_age_s", "messages", "bad_messages")
BRIEF_GIMBAL = ("mount", "interpretation")
_VOLATILE = "last_message_age_s"  # changes every message: not a detail change
_POSE_DECIMALS = {"lat_deg": 7, "lon_deg": 7, "alt_msl_m": 2, "heading_deg": 1, "t_s": 3}

# Required fields and their JSON types (a subscriber may rely on these being present).
_REQUIRED: dict[str, tuple[type, ...]] = {
    "vehicle_id": (str,), "seq": (int,), "uptime_s": (int, float), "thresholds": (list,),
    "proportion_at_or_above": (dict,), "mean_pd": (int, float),
    "expected_false_alarms": (int, float), "cells_free": (int,), "cells_observed": (int,),
    "frames": (dict,), "link": (dict,), "gimbal": (dict,), "grid": (dict,),
    "tiles_seq": (int,), "faults": (dict,),
}
_GRID: dict[str, tuple[type, ...]] = {
    "hash": (str,), "x0_m": (int, float), "y0_m": (int, float), "cell_size_m": (int, float),
    "n_rows": (int,), "n_cols": (int,), "tile_size": (int,), "origin": (dict,),
}


def encode_status(fields: Mapping[str, Any]) -> bytes:
    """JSON bytes of a status object: ``schema`` and ``version`` first, then ``fields``.
    Non-finite floats become null (JSON has no NaN)."""
    doc = {"schema": STATUS_SCHEMA, "version": STATUS_VERSION, **fields}
    return json.dumps(_finite(doc), separators=(",", ":"), allow_nan=False).encode()


class StatusEncoder:
    """Encodes one daemon's statuses in turn (docs/protocol.md "status": full and brief).

    ``encode(fields)`` -> the JSON bytes. A status is full (``"full": true``, every field
    as given) when it is the first, every ``full_every``-th, or when its detail differs
    from the last full one's; otherwise brief (``"full": false``): ``link`` and ``gimbal``
    cut to BRIEF_LINK / BRIEF_GIMBAL, ``grid.origin`` empty, ``faults`` without its zero
    counts, no ``checkpoint``. The detail is what a brief status leaves out, less the
    message ages that change every time. Both kinds carry every required field, so any
    version-1 receiver reads both. Pose numbers are rounded to what they mean (1 cm in
    latitude and longitude, 0.1 deg, 1 ms)."""

    def __init__(self, full_every: int = FULL_EVERY) -> None:
        if full_every < 1:
            raise ValueError(f"full_every: expected >= 1, got {full_every}")
        self.full_every = full_every
        self._since_full: int | None = None
        self._detail: str | None = None

    def encode(self, fields: Mapping[str, Any]) -> bytes:
        doc = dict(fields)
        pose = doc.get("pose")
        if isinstance(pose, Mapping):
            doc["pose"] = {k: round(v, _POSE_DECIMALS[k]) if k in _POSE_DECIMALS
                           and isinstance(v, float) and math.isfinite(v) else v
                           for k, v in pose.items()}
        detail = _detail_signature(doc)
        if (self._since_full is None or self._since_full + 1 >= self.full_every
                or detail != self._detail):
            self._since_full, self._detail = 0, detail
            return encode_status({**doc, "full": True})
        self._since_full += 1
        return encode_status(_brief(doc))


def _sub(doc: Mapping[str, Any], name: str) -> Mapping[str, Any]:
    v = doc.get(name)
    return v if isinstance(v, Mapping) else {}


def _brief(doc: Mapping[str, Any]) -> dict[str, Any]:
    out = {**doc, "full": False}
    for name, keep in (("link", BRIEF_LINK), ("gimbal", BRIEF_GIMBAL)):
        if name in doc:
            out[name] = {k: v for k, v in _sub(doc, name).items() if k in keep}
    if "origin" in _sub(doc, "grid"):
        out["grid"] = {**_sub(doc, "grid"), "origin": {}}
    if "faults" in doc:
        out["faults"] = {k: v for k, v in _sub(doc, "faults").items() if v != 0}
    out.pop("checkpoint", None)
    return out


def _detail_signature(doc: Mapping[str, Any]) -> str:
    """What a brief status leaves out (bar zero fault counts), without the message ages
    that change every time, as JSON."""
    def strip(v: Any) -> Any:
        if isinstance(v, Mapping):
            return {k: strip(x) for k, x in v.items() if k != _VOLATILE}
        if isinstance(v, (list, tuple)):
            return [strip(x) for x in v]
        return v
    detail = {"link": {k: v for k, v in _sub(doc, "link").items() if k not in BRIEF_LINK},
              "gimbal": {k: v for k, v in _sub(doc, "gimbal").items()
                         if k not in BRIEF_GIMBAL},
              "origin": _sub(doc, "grid").get("origin"), "checkpoint": doc.get("checkpoint")}
    return json.dumps(_finite(strip(detail)), sort_keys=True, default=str)


def merge_status(last: Mapping[str, Any] | None, doc: dict[str, Any]) -> dict[str, Any]:
    """A decoded status completed with what a brief one leaves out, from ``last`` (the
    receiver's previous merged status of the same daemon run): the detail of ``link``,
    ``gimbal``, ``grid.origin`` and ``checkpoint``; fault counts it omits are 0. Full
    statuses (and those of a daemon that does not say ``full``) come back as they are."""
    if doc.get("full", True) is not False or last is None:
        return doc
    out = dict(doc)
    for name in ("link", "gimbal"):
        out[name] = {**_sub(last, name), **_sub(doc, name)}
    if not _sub(doc, "grid").get("origin"):
        out["grid"] = {**_sub(doc, "grid"), "origin": _sub(last, "grid").get("origin", {})}
    out["faults"] = {**{k: 0 for k in _sub(last, "faults")}, **_sub(doc, "faults")}
    if "checkpoint" not in doc and "checkpoint" in last:
        out["checkpoint"] = last["checkpoint"]
    return out


def _finite(v: Any) -> Any:
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, Mapping):
        return {str(k): _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    return v


def decode_status(payload: bytes, key: str = "status") -> dict[str, Any]:
    """Parse and validate a status object (schema, version, required fields and types,
    the grid description). Raises BusPayloadError naming ``key`` and the field."""
    def bad(why: str) -> BusPayloadError:
        return BusPayloadError(f"{key}: not a usable status: {why}")

    doc = json_object(payload, MAX_STATUS_BYTES, bad)
    check_schema(doc, STATUS_SCHEMA, STATUS_VERSION, bad)
    _check_types(doc, _REQUIRED, "", bad)
    _check_types(doc["grid"], _GRID, "grid.", bad)
    g = doc["grid"]
    if not (g["n_rows"] > 0 and g["n_cols"] > 0 and g["cell_size_m"] > 0
            and g["tile_size"] > 0 and len(g["hash"]) == 16):
        raise bad("grid: expected positive n_rows, n_cols, cell_size_m, tile_size and a "
                  "16-digit hash")
    for name, share in doc["proportion_at_or_above"].items():
        if not isinstance(share, (int, float)) or not 0 <= share <= 1:
            raise bad(f"proportion_at_or_above.{name}: expected a share in [0, 1]")
    return doc


def _check_types(doc: Mapping[str, Any], spec: Mapping[str, tuple[type, ...]], prefix: str,
                 bad) -> None:
    for name, types in spec.items():
        if name not in doc:
            raise bad(f"{prefix}{name} missing")
        v = doc[name]
        if isinstance(v, bool) or not isinstance(v, types):
            raise bad(f"{prefix}{name}: expected {'/'.join(t.__name__ for t in types)}, "
                      f"got {type(v).__name__}")
