"""The detections payload (``pdcov/<id>/detections``, and the answer of the queryable
``pdcov/<id>/candidates``) and ``detections.json`` of ``pdcov evaluate``: one JSON document,
built in one place (``detections_document``) for the daemon and the offline evaluation.

    {"schema": "pdcov.detections", "version": 2, "vehicle": id,
     "detections": [{"t_boot_s", "time_utc", "class", "confidence", "box_px": [l, t, w, h],
                     "lat_deg", "lon_deg", "alt_msl_m", "x_m", "y_m", "sigma_m",
                     "candidate", "uid"}],
     "candidates": [{"id", "uid", "class", "lat_deg", "lon_deg", "alt_msl_m", "x_m", "y_m",
                     "sigma_m", "hits", "looks", "p_person", "pd", "pfa", "confidence",
                     "first_t_boot_s", "last_t_boot_s", "first_time_utc",
                     "last_time_utc"}]}

``time_utc``, ``first_time_utc``, ``last_time_utc``: the frames' UTC from the autopilot's
real-time clock (core/utc_clock.py ``utc_text``: '2026-12-06T21:42:01.250Z'), null when it
was unknown; optional, so a document without them (an older daemon's) is read as null, and
an older watcher, which reads the fields it knows, ignores them.

A published message holds the detections new since the last one and the current state of
every candidate they touched; the candidates query answers every candidate (and no
detection), so a ground station that joins late catches up. x_m, y_m: ENU metres about the
mission's origin; lat/lon WGS84 degrees, alt_msl_m the ground point's altitude (docs/
protocol.md "detections"). A detection's ``uid`` is its candidate's (core/detections.py
UID_RULE): the candidates touched are in the message, bar one evicted since (the tracker
forgets its stalest unconfirmed candidate for a new one), whose uid the caller gives.
Version 1 (before uids) is refused: the daemon and the watcher ship together.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from pdcov.bus.errors import Refusal, Refuser
from pdcov.bus.grid_state import MAX_ENU_M
from pdcov.bus.json_doc import Fields, check_schema, is_number, json_object
from pdcov.core.detections import (
    CLASS_NAME_RULE,
    UID_RULE,
    Candidate,
    Detection,
    valid_class_name,
    valid_uid,
)
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.utc_clock import UTC_TEXT, utc_text

__all__ = ["DETECTIONS_SCHEMA", "DETECTIONS_VERSION", "LIKELY_P_PERSON", "MAX_CANDIDATES",
           "MAX_DETECTIONS", "MAX_DETECTIONS_BYTES", "P_PERSON_DIGITS", "decode_detections",
           "detections_document", "encode_detections"]

DETECTIONS_SCHEMA = "pdcov.detections"
DETECTIONS_VERSION = 2
MAX_DETECTIONS = 10_000
"""Most detections per message."""
MAX_CANDIDATES = 10_000
"""Most candidates per message, and per flight (detection/candidates.py holds no more)."""
MAX_DETECTIONS_BYTES = 8 << 20
"""Largest detections payload accepted (10,000 candidates are about 3 MB)."""
_U32 = 2**32 - 1
_MAX_BOOT_S = _U32 / 1000  # time_boot_ms is a uint32
P_PERSON_DIGITS = 4
"""Decimal digits of ``p_person`` on the wire."""
LIKELY_P_PERSON = 0.5
"""A pin at least this probable is counted as likely (the status's summary, the views)."""


def _geodetic(r_enu_m: np.ndarray, origin: Origin) -> dict[str, float]:
    lat, lon, alt = enu_to_geodetic(r_enu_m, origin)
    return {"lat_deg": round(float(lat), 8), "lon_deg": round(float(lon), 8),
            "alt_msl_m": round(float(alt), 3), "x_m": round(float(r_enu_m[0]), 3),
            "y_m": round(float(r_enu_m[1]), 3)}


def detections_document(detections: Sequence[Detection], candidates: Sequence[Candidate],
                        origin: Origin, vehicle_id: str,
                        uid_of: Callable[[int], str] | None = None) -> dict[str, Any]:
    """The detections document (module docstring) of these detections and candidates, in
    the order given; positions rounded to 1e-8 degrees and millimetres, ``p_person`` to
    P_PERSON_DIGITS digits. A detection's uid is its candidate's when that candidate is
    among ``candidates``, else ``uid_of(candidate_id)`` (the tracker's uid of one evicted
    since); ValueError naming the candidate ids without either."""
    uids = {c.candidate_id: c.uid for c in candidates}
    missing = sorted({d.candidate_id for d in detections} - uids.keys())
    if missing:
        if uid_of is None:
            raise ValueError(f"detections of candidates {missing[:10]} without those "
                             "candidates in the document: their uids are unknown")
        uids.update((cid, uid_of(cid)) for cid in missing)
    return {
        "schema": DETECTIONS_SCHEMA, "version": DETECTIONS_VERSION, "vehicle": vehicle_id,
        "detections": [{
            "t_boot_s": d.t_boot_s, "time_utc": utc_text(d.unix_s),
            "class": d.box.class_name, "confidence": d.box.confidence,
            "box_px": list(d.box.box_px), **_geodetic(d.r_enu_m, origin),
            "sigma_m": round(d.sigma_m, 3), "candidate": d.candidate_id,
            "uid": uids[d.candidate_id]}
            for d in detections],
        "candidates": [{
            "id": c.candidate_id, "uid": c.uid, "class": c.class_name,
            **_geodetic(c.r_enu_m, origin), "sigma_m": round(c.sigma_m, 3), "hits": c.hits,
            "looks": c.looks, "p_person": round(c.p_person, P_PERSON_DIGITS), "pd": c.pd,
            "pfa": c.pfa, "confidence": c.confidence, "first_t_boot_s": c.first_t_boot_s,
            "last_t_boot_s": c.last_t_boot_s, "first_time_utc": utc_text(c.first_unix_s),
            "last_time_utc": utc_text(c.last_unix_s)}
            for c in candidates]}


def encode_detections(doc: dict[str, Any]) -> bytes:
    """Compact JSON bytes of a ``detections_document``."""
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()


def decode_detections(payload: bytes, key: str = "detections",
                      vehicle_id: str | None = None) -> dict[str, Any]:
    """Parse and validate a detections document: size (MAX_DETECTIONS_BYTES), strict JSON,
    schema and version, the vehicle (``vehicle_id`` when given: the one in the key), at most
    MAX_DETECTIONS detections and MAX_CANDIDATES candidates with every field's type and
    range (docs/protocol.md "Validation and bounds"). Raises BusPayloadError naming ``key``
    and the field."""
    bad = Refuser(f"{key}: not a usable detections message")
    doc = json_object(payload, MAX_DETECTIONS_BYTES, bad)
    if doc.get("schema") == DETECTIONS_SCHEMA and doc.get("version") == 1:
        raise bad(f"version 1 (a daemon from before candidate uids), expected "
                  f"{DETECTIONS_VERSION}: update the daemon and pdcov watch together",
                  Refusal.MALFORMED)
    check_schema(doc, DETECTIONS_SCHEMA, DETECTIONS_VERSION, bad)
    f = Fields(doc, bad)
    f.vehicle_id("vehicle", vehicle_id)
    detections = f.items("detections", MAX_DETECTIONS)
    for i, item in enumerate(detections):
        d = Fields(item, bad, f"detections[{i}].")
        d.number("t_boot_s", 0.0, _MAX_BOOT_S)
        _utc(d, "time_utc")
        _class(d)
        d.number("confidence", 0.0, 1.0)
        px = d.doc.get("box_px")
        if not (isinstance(px, list) and len(px) == 4 and all(is_number(v) for v in px)
                and px[2] > 0 and px[3] > 0):
            raise bad(f"{d.where}box_px: expected [left, top, width, height] with width "
                      f"and height > 0 (px), got {px!r}"[:300])
        _position(d)
        d.integer("candidate", 0, _U32)
        _uid(d)
    uids: dict[int, str] = {}
    for i, item in enumerate(f.items("candidates", MAX_CANDIDATES)):
        c = Fields(item, bad, f"candidates[{i}].")
        cid = c.integer("id", 0, _U32)
        uid = _uid(c)
        if uids.setdefault(cid, uid) != uid:
            raise bad(f"{c.where}uid {uid!r}: candidate {cid} is also {uids[cid]!r}")
        _class(c)
        _position(c)
        looks = c.integer("looks", 0, _U32)
        hits = c.integer("hits", 0, _U32)
        if hits > looks:
            raise bad(f"{c.where}hits {hits} > looks {looks}: at most one hit per look")
        for name in ("p_person", "pd", "pfa", "confidence"):
            c.number(name, 0.0, 1.0)
        first = c.number("first_t_boot_s", 0.0, _MAX_BOOT_S)
        c.number("last_t_boot_s", first, _MAX_BOOT_S)  # [first, ...]: not before the first
        _utc(c, "first_time_utc")
        _utc(c, "last_time_utc")
    for i, item in enumerate(detections):  # a detection's uid is its candidate's
        want = uids.get(item["candidate"], item["uid"])
        if item["uid"] != want:
            raise bad(f"detections[{i}].uid {item['uid']!r}: its candidate "
                      f"{item['candidate']} is {want!r}")
    return doc


def _utc(f: Fields, name: str) -> None:
    if f.doc.get(name) is not None:
        f.string(name, UTC_TEXT, 24)


def _uid(f: Fields) -> str:
    uid = f.doc.get("uid")
    if not valid_uid(uid):
        raise f.bad(f"{f.where}uid {uid!r}: expected {UID_RULE}"[:300])
    return str(uid)


def _class(f: Fields) -> None:
    name = f.doc.get("class")
    if not valid_class_name(name):
        raise f.bad(f"{f.where}class {name!r}: expected {CLASS_NAME_RULE}"[:300])


def _position(f: Fields) -> None:
    f.number("lat_deg", -90.0, 90.0)
    f.number("lon_deg", -180.0, 360.0)
    f.number("alt_msl_m")
    f.number("x_m", -MAX_ENU_M, MAX_ENU_M)
    f.number("y_m", -MAX_ENU_M, MAX_ENU_M)
    f.number("sigma_m", 0.0, MAX_ENU_M)
