"""The footprint payload (queryable ``pdcov/<id>/footprint``): a GeoJSON Feature (RFC 7946:
WGS84 lon/lat degrees) whose geometry is the current camera footprint's Polygon, or null when
the camera sees no ground; properties ``schema`` "pdcov.footprint", ``version`` 1,
``vehicle_id`` and ``t_s`` (autopilot time, s). The detector's frames payload is bus/frames.py.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from pdcov.bus.errors import Refusal, Refuser
from pdcov.bus.json_doc import Fields, check_schema, is_number, json_object

FOOTPRINT_SCHEMA = "pdcov.footprint"
VERSION = 1
MAX_VERTICES = 10_000
MAX_PAYLOAD_BYTES = 1 << 20
"""Largest footprint payload accepted."""


def encode_footprint(vehicle_id: str, t_s: float, lon_lat_deg: np.ndarray | None) -> bytes:
    """GeoJSON bytes; ``lon_lat_deg`` (M, 2) is the ring (closed here if open), None or
    fewer than 3 points for no footprint."""
    geometry = None
    if lon_lat_deg is not None and len(lon_lat_deg) >= 3:
        ring = [[round(float(lon), 8), round(float(lat), 8)] for lon, lat in lon_lat_deg]
        if ring[0] != ring[-1]:
            ring.append(ring[0])
        geometry = {"type": "Polygon", "coordinates": [ring]}
    doc = {"type": "Feature", "geometry": geometry,
           "properties": {"schema": FOOTPRINT_SCHEMA, "version": VERSION,
                          "vehicle_id": vehicle_id,
                          "t_s": t_s if math.isfinite(t_s) else None}}
    return json.dumps(doc, separators=(",", ":")).encode()


def decode_footprint(payload: bytes, key: str = "footprint") -> dict[str, Any]:
    """Validate a footprint Feature (schema, version, a Polygon of finite lon/lat in range
    or null). Raises BusPayloadError naming ``key``."""
    bad = Refuser(f"{key}: not a usable footprint")
    doc = json_object(payload, MAX_PAYLOAD_BYTES, bad)
    props = doc.get("properties")
    if doc.get("type") != "Feature" or not isinstance(props, dict):
        raise bad("expected a GeoJSON Feature with properties", Refusal.MALFORMED)
    check_schema(props, FOOTPRINT_SCHEMA, VERSION, bad, "properties.")
    f = Fields(props, bad, "properties.")
    f.string("vehicle_id", max_len=64)
    f.number_or_null("t_s")
    geom = doc.get("geometry")
    if geom is None:
        return doc
    rings = geom.get("coordinates") if isinstance(geom, dict) else None
    if not isinstance(geom, dict) or geom.get("type") != "Polygon" \
            or not isinstance(rings, list) or len(rings) != 1 or not isinstance(rings[0], list):
        raise bad("geometry: expected a Polygon of one ring, or null")
    ring = rings[0]
    if len(ring) > MAX_VERTICES:
        raise bad(f"geometry: {len(ring)} positions, more than MAX_VERTICES {MAX_VERTICES}",
                  Refusal.OVER_BOUND)
    if len(ring) < 4:
        raise bad(f"geometry: {len(ring)} positions, a closed ring has at least 4")
    for p in ring:
        if (not isinstance(p, list) or len(p) != 2 or not all(is_number(v) for v in p)
                or not (-180 <= p[0] <= 180 and -90 <= p[1] <= 90)):
            raise bad(f"geometry: position {p!r} is not [lon, lat] in degrees"[:200])
    return doc

