"""The status payload (``pdcov/<id>/status``, about 1 Hz): UTF-8 JSON, one object.

Fields (docs/protocol.md "status" gives each one's meaning and unit): schema, version,
vehicle_id, seq, uptime_s, t_s, thresholds, proportion_at_or_above, mean_pd,
expected_false_alarms, cells_free, cells_observed, frames {used, skipped {reason: n}},
link {...}, pose {lat_deg, lon_deg, alt_msl_m, heading_deg, t_s} or null, gimbal {...},
grid {hash, x0_m, y0_m, cell_size_m, n_rows, n_cols, tile_size, origin {lat_deg,
lon_deg, ground_alt_msl_m}}, tiles_seq, faults {name: n}, checkpoint {...}.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from pdcov.bus.errors import BusPayloadError

STATUS_SCHEMA = "pdcov.status"
STATUS_VERSION = 1
MAX_STATUS_BYTES = 64 * 1024

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

    data = bytes(payload)
    if len(data) > MAX_STATUS_BYTES:
        raise bad(f"{len(data)} bytes, more than {MAX_STATUS_BYTES}")
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise bad(f"not UTF-8 JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise bad("expected a JSON object")
    if doc.get("schema") != STATUS_SCHEMA or doc.get("version") != STATUS_VERSION:
        raise bad(f"schema {doc.get('schema')!r} version {doc.get('version')!r}, expected "
                  f"{STATUS_SCHEMA!r} version {STATUS_VERSION}")
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
