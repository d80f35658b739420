"""The footprint payload (queryable ``pdcov/<id>/footprint``) and the frames payload that an
onboard detector publishes on ``pdcov/<id>/frames``.

Footprint: a GeoJSON Feature (RFC 7946: WGS84 lon/lat degrees) whose geometry is the
current camera footprint's Polygon, or null when the camera sees no ground; properties
``schema`` "pdcov.footprint", ``version`` 1, ``vehicle_id`` and ``t_s`` (autopilot time, s).

Frames: UTF-8 JSON ``{"schema": "pdcov.frames", "version": 1, "t_boot_s": [t, ...]}``: the
times of the frames the detector processed, in seconds of the autopilot's boot clock
(time_boot_ms / 1000), at most MAX_FRAMES per message.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from pdcov.bus.errors import Refusal, Refuser
from pdcov.bus.json_doc import Fields, check_schema, is_number, json_object

FOOTPRINT_SCHEMA = "pdcov.footprint"
FRAMES_SCHEMA = "pdcov.frames"
VERSION = 1
MAX_FRAMES = 1000
MAX_VERTICES = 10_000
MAX_PAYLOAD_BYTES = 1 << 20
"""Largest footprint or frames payload accepted."""


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


def encode_frames(t_boot_s: Sequence[float]) -> bytes:
    """A frames message for the given frame times (autopilot boot clock, s)."""
    return json.dumps({"schema": FRAMES_SCHEMA, "version": VERSION,
                       "t_boot_s": [float(t) for t in t_boot_s]}).encode()


def decode_frames(payload: bytes, key: str = "frames") -> tuple[float, ...]:
    """The frame times of a frames message: 1..MAX_FRAMES finite numbers >= 0."""
    bad = Refuser(f"{key}: not a usable frames message")
    doc = json_object(payload, MAX_PAYLOAD_BYTES, bad)
    check_schema(doc, FRAMES_SCHEMA, VERSION, bad)
    t = doc.get("t_boot_s")
    if (not isinstance(t, list) or not 1 <= len(t) <= MAX_FRAMES
            or not all(is_number(v) and v >= 0 for v in t)):
        raise bad(f"t_boot_s: expected a list of 1..{MAX_FRAMES} times >= 0 (s)")
    return tuple(float(v) for v in t)
