"""The re-tasking payloads (queryable ``pdcov/<id>/retask``, docs/protocol.md "retask"): a
ground station's signed query carries a mission for the vehicle's autopilot; the daemon's
reply says whether the autopilot took it.

Request, version 2: an envelope (UTF-8 JSON) {schema "pdcov.retask_signed", version 2,
key_id, body, signature}. ``body`` is the base64 (RFC 4648, with padding) of the exact
bytes signed: UTF-8 JSON {schema "pdcov.retask", version 2, vehicle_id, key_id, nonce (32
hex digits: 16 random bytes, never reused), issued_unix_s (UTC s when signed), plan_hash
(16 hex digits: ``plan_hash(items)``, so that the reply, the logs and the status name the
mission sent), description (at most 200 characters), items}. ``signature``: the base64 of
the 64-byte Ed25519 signature of those body bytes by the operator key ``key_id``
(bus/operator_keys.py), which the body names again. The receiver checks the signature over
the bytes as received, before parsing them: nothing is re-serialised.

Items: at most MAX_RETASK_ITEMS mission items as the upload sends them as
MISSION_ITEM_INT (telemetry/upload.py), each {command, frame, params [p1, p2, p3, p4]
(null: NaN, "unchanged"), lat_deg, lon_deg, z_m, autocontinue}. Only the commands of a
coverage or vantage plan (MISSION_COMMANDS: waypoint, loiter time, take-off, land, return
to launch, speed change, gimbal pitch-yaw, mount control, camera zoom) in the frames plans
use (MISSION_FRAMES) pass: a re-tasking payload cannot carry a mode change or an arming.

Reply: schema "pdcov.retask_reply", version 1, vehicle_id, plan_hash (null when the
request did not decode), accepted, reason (the autopilot's MAV_MISSION_RESULT name,
TIMEOUT, or why the daemon refused it: ``RetaskRefusal``), detail, items (items uploaded,
ArduPilot's home included).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from pdcov.bus.errors import BusPayloadError, Refusal, Refuser
from pdcov.bus.json_doc import Fields, check_schema, is_number, json_object
from pdcov.bus.operator_keys import OperatorKey
from pdcov.core.mission import (
    MAV_CMD_DO_CHANGE_SPEED,
    MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
    MAV_CMD_DO_MOUNT_CONTROL,
    MAV_CMD_NAV_LAND,
    MAV_CMD_NAV_LOITER_TIME,
    MAV_CMD_NAV_RETURN_TO_LAUNCH,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_NAV_WAYPOINT,
    MAV_CMD_SET_CAMERA_ZOOM,
    MAV_FRAME_GLOBAL,
    MAV_FRAME_GLOBAL_RELATIVE_ALT,
    MAV_FRAME_GLOBAL_TERRAIN_ALT,
    MAV_FRAME_MISSION,
    MissionItem,
)

RETASK_SCHEMA = "pdcov.retask"
SIGNED_SCHEMA = "pdcov.retask_signed"
RETASK_REPLY_SCHEMA = "pdcov.retask_reply"
RETASK_VERSION = 2
REPLY_VERSION = 1
MAX_RETASK_ITEMS = 1000
"""Mission items a request may carry (ArduCopter on a 2 MB board holds about 700 more;
a re-fly of a few gaps needs tens)."""
MAX_RETASK_BYTES = 256 * 1024
MAX_REPLY_BYTES = 4096
MISSION_COMMANDS = frozenset({MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_LOITER_TIME,
                              MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_LAND,
                              MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_CMD_DO_CHANGE_SPEED,
                              MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, MAV_CMD_DO_MOUNT_CONTROL,
                              MAV_CMD_SET_CAMERA_ZOOM})
MISSION_FRAMES = frozenset({MAV_FRAME_GLOBAL, MAV_FRAME_MISSION, MAV_FRAME_GLOBAL_RELATIVE_ALT,
                            MAV_FRAME_GLOBAL_TERRAIN_ALT})
MAX_PARAM = 1e7
MIN_Z_M, MAX_Z_M = -1000.0, 20000.0
PLAN_HASH = re.compile(r"[0-9a-f]{16}")
KEY_ID = re.compile(r"[0-9a-f]{16}")
NONCE = re.compile(r"[0-9a-f]{32}")
MAX_UNIX_S = 1e11


class UnsignedRequest(BusPayloadError):
    """A request without a signature (a version 1 request, or an envelope without one)."""


@dataclass(frozen=True, slots=True)
class SignedEnvelope:
    """A request as received: the key it names, the exact body bytes and the signature
    over them (not verified yet)."""

    key_id: str
    body: bytes
    signature: bytes


@dataclass(frozen=True, slots=True)
class RetaskRequest:
    """A decoded request body: the mission items to upload (no ArduPilot home item: the
    daemon adds its own), the hash that names them, and what the signature covers."""

    vehicle_id: str
    key_id: str
    nonce: str
    issued_unix_s: float
    plan_hash: str
    description: str
    items: tuple[MissionItem, ...]


@dataclass(frozen=True, slots=True)
class RetaskReply:
    """A decoded reply (module docstring)."""

    vehicle_id: str
    plan_hash: str | None
    accepted: bool
    reason: str
    detail: str
    items: int


def _null_nan(v: float) -> float | None:
    return None if math.isnan(v) else float(v)


def _item_doc(it: MissionItem) -> dict[str, Any]:
    return {"command": it.command, "frame": it.frame,
            "params": [_null_nan(p) for p in (it.param1, it.param2, it.param3, it.param4)],
            "lat_deg": it.lat_deg, "lon_deg": it.lon_deg, "z_m": it.z_m,
            "autocontinue": it.autocontinue}


def _json(doc: Any) -> bytes:
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()


def plan_hash(items: Sequence[MissionItem]) -> str:
    """SHA-256 (16 hex digits) of the items as the request carries them."""
    return hashlib.sha256(_json([_item_doc(it) for it in items])).hexdigest()[:16]


def encode_signed_retask(key: OperatorKey, vehicle_id: str, items: Sequence[MissionItem],
                         description: str, issued_unix_s: float, nonce: str) -> bytes:
    """The signed request for ``items`` (mission items without a home item), issued at
    ``issued_unix_s`` (UTC s) with ``nonce`` (32 fresh random hex digits)."""
    body = _json({"schema": RETASK_SCHEMA, "version": RETASK_VERSION,
                  "vehicle_id": vehicle_id, "key_id": key.id, "nonce": nonce,
                  "issued_unix_s": issued_unix_s, "plan_hash": plan_hash(items),
                  "description": description[:200],
                  "items": [_item_doc(it) for it in items]})
    return _json({"schema": SIGNED_SCHEMA, "version": RETASK_VERSION, "key_id": key.id,
                  "body": base64.b64encode(body).decode(),
                  "signature": base64.b64encode(key.sign(body)).decode()})


def _base64(f: Fields, name: str, bad: Refuser) -> bytes:
    text = f.string(name, max_len=MAX_RETASK_BYTES)
    try:
        return base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError):
        raise bad(f"{name}: not base64") from None


def open_envelope(payload: bytes, key: str = "retask") -> SignedEnvelope:
    """The envelope of a request (module docstring), its signature not checked yet:
    UnsignedRequest for a request without one (version 1, or no signature), else
    BusPayloadError naming ``key`` and the field."""
    bad = Refuser(f"{key}: not a usable re-tasking request")
    doc = json_object(payload, MAX_RETASK_BYTES, bad)
    if doc.get("schema") == RETASK_SCHEMA or (doc.get("schema") == SIGNED_SCHEMA
                                              and doc.get("signature") is None):
        raise UnsignedRequest(f"{key}: an unsigned re-tasking request (schema "
                              f"{doc.get('schema')!r} version {doc.get('version')!r}): "
                              f"expected a {SIGNED_SCHEMA!r} version {RETASK_VERSION} "
                              "envelope signed by an operator key", Refusal.MALFORMED)
    check_schema(doc, SIGNED_SCHEMA, RETASK_VERSION, bad)
    f = Fields(doc, bad)
    key_id = f.string("key_id", KEY_ID)
    signature = _base64(f, "signature", bad)
    if len(signature) != 64:
        raise bad(f"signature: {len(signature)} bytes, an Ed25519 signature has 64")
    return SignedEnvelope(key_id, _base64(f, "body", bad), signature)


def decode_retask_body(body: bytes, key: str = "retask") -> RetaskRequest:
    """Validate a signed body (its signature checked first): size, strict JSON, schema and
    version, 1..MAX_RETASK_ITEMS items of MISSION_COMMANDS in MISSION_FRAMES with positions
    in range and finite parameters (or null), and the plan hash matching them. The vehicle
    id, time and nonce are the receiver's to judge. Raises BusPayloadError naming ``key``
    and the field."""
    bad = Refuser(f"{key}: not a usable re-tasking request")
    doc = json_object(body, MAX_RETASK_BYTES, bad)
    check_schema(doc, RETASK_SCHEMA, RETASK_VERSION, bad)
    f = Fields(doc, bad)
    vid = f.vehicle_id("vehicle_id")
    key_id = f.string("key_id", KEY_ID)
    nonce = f.string("nonce", NONCE)
    issued = f.number("issued_unix_s", 0.0, MAX_UNIX_S)
    claimed = f.string("plan_hash", PLAN_HASH)
    description = f.string("description", max_len=200)
    raw = f.items("items", MAX_RETASK_ITEMS)
    if not raw:
        raise bad("items: expected at least one mission item")
    items = tuple(_item(Fields(d, bad, f"items[{i}]."), bad) for i, d in enumerate(raw))
    if plan_hash(items) != claimed:
        raise bad(f"plan_hash {claimed}: the items hash to {plan_hash(items)} (altered "
                  "or truncated on the way?)")
    return RetaskRequest(vid, key_id, nonce, issued, claimed, description, items)


def _item(f: Fields, bad: Refuser) -> MissionItem:
    command = f.integer("command", 0, 65535)
    if command not in MISSION_COMMANDS:
        raise bad(f"{f.where}command: {command} is not one a coverage plan uses (expected "
                  f"one of {sorted(MISSION_COMMANDS)}: waypoint, loiter time, return to "
                  "launch, land, take-off, speed change, gimbal pitch-yaw, mount control, "
                  "camera zoom)")
    frame = f.integer("frame", 0, 255)
    if frame not in MISSION_FRAMES:
        raise bad(f"{f.where}frame: {frame}, expected one of {sorted(MISSION_FRAMES)}")
    params = f.items("params", 4)
    if len(params) != 4 or not all(p is None or (is_number(p) and abs(p) <= MAX_PARAM)
                                   for p in params):
        raise bad(f"{f.where}params: expected 4 numbers within {MAX_PARAM:g} (or null)")
    autocontinue = f.doc.get("autocontinue")
    if not isinstance(autocontinue, bool):
        raise bad(f"{f.where}autocontinue: expected true or false")
    p1, p2, p3, p4 = (math.nan if p is None else float(p) for p in params)
    return MissionItem(command, frame, p1, p2, p3, p4, f.number("lat_deg", -90.0, 90.0),
                       f.number("lon_deg", -180.0, 180.0), f.number("z_m", MIN_Z_M, MAX_Z_M),
                       autocontinue)


def encode_retask_reply(vehicle_id: str, plan_hash: str | None, accepted: bool, reason: str,
                        detail: str, items: int) -> bytes:
    return _json({"schema": RETASK_REPLY_SCHEMA, "version": REPLY_VERSION,
                  "vehicle_id": vehicle_id, "plan_hash": plan_hash, "accepted": accepted,
                  "reason": reason[:64], "detail": detail[:500], "items": items})


def decode_retask_reply(payload: bytes, key: str = "retask",
                        vehicle_id: str | None = None) -> RetaskReply:
    """Validate a reply (module docstring); BusPayloadError naming ``key`` and the field."""
    bad = Refuser(f"{key}: not a usable re-tasking reply")
    doc = json_object(payload, MAX_REPLY_BYTES, bad)
    check_schema(doc, RETASK_REPLY_SCHEMA, REPLY_VERSION, bad)
    f = Fields(doc, bad)
    vid = f.vehicle_id("vehicle_id", vehicle_id)
    hash_ = None if doc.get("plan_hash") is None else f.string("plan_hash", PLAN_HASH)
    accepted = doc.get("accepted")
    if not isinstance(accepted, bool):
        raise bad("accepted: expected true or false", Refusal.BAD_FIELD)
    return RetaskReply(vid, hash_, accepted, f.string("reason", max_len=64),
                       f.string("detail", max_len=500),
                       f.integer("items", 0, MAX_RETASK_ITEMS + 1))
