"""The status payload (``pdcov/<id>/status``, about 1 Hz): UTF-8 JSON, one object.

Fields (docs/protocol.md "status" gives each one's meaning and unit): schema, version,
vehicle_id, seq, uptime_s, t_s, thresholds, proportion_at_or_above, mean_pd,
expected_false_alarms, cells_free, cells_observed, frames {used, skipped {reason: n}},
link {...}, pose {lat_deg, lon_deg, alt_msl_m, heading_deg, t_s, gnss_h_acc_m} or null,
gimbal {...},
grid {hash, x0_m, y0_m, cell_size_m, n_rows, n_cols, tile_size, origin {lat_deg,
lon_deg, ground_alt_msl_m}}, tiles_seq, faults {name: n}, checkpoint {...}, full, and
with a DEM terrain_check {margin_m, checked, mismatches, refused, largest, latest}, and
once a re-tasking request came retask {enabled, uploading, refused, last}, and once the
detector is followed pins {candidates, likely, top {uid, p_person, looks, hits} or null}.

``StatusEncoder`` keeps the daemon's status under its 1 kB/s budget: the detail that rarely
changes (the link's negotiation, the gimbal's description, the checkpoint) goes out in
full statuses only -- the first, every ``FULL_EVERY``-th and any whose detail changed --
and the others carry the same required fields with a brief ``link`` and ``gimbal`` (and no
``checkpoint``, ``terrain_check``, ``retask`` or ``pins``).
``merge_status`` gives a receiver the latest values with the last full status's detail.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from pdcov.bus.errors import Refusal, Refuser
from pdcov.bus.grid_state import GRID_HASH, MAX_ENU_M
from pdcov.bus.json_doc import Fields, check_schema, finite_or_null, is_number, json_object
from pdcov.bus.tiles import MAX_TILE_SIZE
from pdcov.config.mission import MAX_THRESHOLDS
from pdcov.core.detections import UID_RULE, valid_uid
from pdcov.core.domain import MAX_GRID_CELLS
from pdcov.telemetry.samples import MAX_GNSS_ACCURACY_M

STATUS_SCHEMA = "pdcov.status"
STATUS_VERSION = 1
MAX_STATUS_BYTES = 64 * 1024
"""Largest status payload a receiver accepts (the daemon's are about 1.6 kB)."""
MAX_NAMED_COUNTS = 256
"""Most entries of a count object (``frames.skipped``, ``faults``)."""
FULL_EVERY = 20
"""Every this many statuses (20 s at 1 Hz) one is full even when no detail changed."""
BRIEF_LINK = ("state", "last_message_age_s", "messages", "bad_messages")
BRIEF_GIMBAL = ("mount", "interpretation")
_VOLATILE = "last_message_age_s"  # changes every message: not a detail change
CHECKPOINT_PROGRESS = ("last_t_s", "written_unix_s", "frames")
"""Checkpoint fields that change with every checkpoint written: carried by full statuses,
not a detail change (else every checkpoint's status would be full: 1,061-1,071 B per
status, over the 1 kB/s budget, in benchmarks.fleet)."""
_POSE_DECIMALS = {"lat_deg": 7, "lon_deg": 7, "alt_msl_m": 2, "heading_deg": 1, "t_s": 3,
                  "gnss_h_acc_m": 3}
_SUMMARY_DECIMALS = {"t_s": 3, "mean_pd": 6, "expected_false_alarms": 4}
"""The summary's numbers to what they mean (1 ms; a millionth of P_D; 1e-4 false alarms),
proportion_at_or_above's shares to 6 decimals: 17-digit floats put the statuses of a busy
flight over the 1 kB/s budget (1,014 B per status in benchmarks.fleet)."""

_U32 = 2**32 - 1
_U64 = 2**64 - 1


def encode_status(fields: Mapping[str, Any]) -> bytes:
    """JSON bytes of a status object: ``schema`` and ``version`` first, then ``fields``.
    Non-finite floats become null (JSON has no NaN)."""
    doc = {"schema": STATUS_SCHEMA, "version": STATUS_VERSION, **fields}
    return json.dumps(finite_or_null(doc), separators=(",", ":"), allow_nan=False).encode()


def _rounded(value: Any, decimals: int) -> Any:
    """A finite float rounded to ``decimals``; anything else as it is."""
    return round(value, decimals) if isinstance(value, float) and math.isfinite(value) \
        else value


class StatusEncoder:
    """Encodes one daemon's statuses in turn (docs/protocol.md "status": full and brief).

    ``encode(fields)`` -> the JSON bytes. A status is full (``"full": true``, every field as
    given) when it is the first, every ``full_every``-th, or when its detail differs from
    the last full one's; otherwise brief (``"full": false``): ``link`` and ``gimbal`` cut to
    BRIEF_LINK / BRIEF_GIMBAL, ``grid.origin`` empty, ``faults`` without its zero counts, no
    ``checkpoint``, ``terrain_check``, ``retask`` or ``pins``. The detail is what a brief
    status leaves out (bar the terrain check, whose counts change with every reading), less
    the message ages that change every time. Both kinds carry every required field, so any
    version-1 receiver reads both. Pose numbers are rounded to what they mean (1 cm in
    latitude and longitude, 0.1 deg, 1 ms, 1 mm of GNSS accuracy), and so are the
    summary's (_SUMMARY_DECIMALS)."""

    def __init__(self, full_every: int = FULL_EVERY) -> None:
        if full_every < 1:
            raise ValueError(f"full_every: expected >= 1, got {full_every}")
        self.full_every = full_every
        self._since_full: int | None = None
        self._detail: str | None = None

    def encode(self, fields: Mapping[str, Any]) -> bytes:
        doc = {k: _rounded(v, _SUMMARY_DECIMALS[k]) if k in _SUMMARY_DECIMALS else v
               for k, v in fields.items()}
        shares = doc.get("proportion_at_or_above")
        if isinstance(shares, Mapping):
            doc["proportion_at_or_above"] = {t: _rounded(v, 6) for t, v in shares.items()}
        pose = doc.get("pose")
        if isinstance(pose, Mapping):
            doc["pose"] = {k: _rounded(v, _POSE_DECIMALS[k]) if k in _POSE_DECIMALS else v
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
    out.pop("terrain_check", None)
    out.pop("retask", None)
    out.pop("pins", None)  # the detections messages carry the pins; this is their summary
    return out


def _detail_signature(doc: Mapping[str, Any]) -> str:
    """What a brief status leaves out (bar zero fault counts), without the message ages
    that change every time and the checkpoint's progress, as JSON."""
    def strip(v: Any) -> Any:
        if isinstance(v, Mapping):
            return {k: strip(x) for k, x in v.items() if k != _VOLATILE}
        if isinstance(v, (list, tuple)):
            return [strip(x) for x in v]
        return v
    detail = {"link": {k: v for k, v in _sub(doc, "link").items() if k not in BRIEF_LINK},
              "gimbal": {k: v for k, v in _sub(doc, "gimbal").items()
                         if k not in BRIEF_GIMBAL},
              "origin": _sub(doc, "grid").get("origin"),
              "checkpoint": {k: v for k, v in _sub(doc, "checkpoint").items()
                             if k not in CHECKPOINT_PROGRESS},
              "retask": doc.get("retask"),
              # A new top pin goes out at once; its figures with the next full status.
              "top_pin": (_sub(_sub(doc, "pins"), "top") or {}).get("uid")}
    return json.dumps(finite_or_null(strip(detail)), sort_keys=True, default=str)


def merge_status(last: Mapping[str, Any] | None, doc: dict[str, Any]) -> dict[str, Any]:
    """A decoded status completed with what a brief one leaves out, from ``last`` (the
    receiver's previous merged status of the same daemon run): the detail of ``link``,
    ``gimbal``, ``grid.origin``, ``checkpoint``, ``pins``; fault counts it omits are 0. Full
    statuses (and those of a daemon that does not say ``full``) come back as they are."""
    if doc.get("full", True) is not False or last is None:
        return doc
    out = dict(doc)
    for name in ("link", "gimbal"):
        out[name] = {**_sub(last, name), **_sub(doc, name)}
    if not _sub(doc, "grid").get("origin"):
        out["grid"] = {**_sub(doc, "grid"), "origin": _sub(last, "grid").get("origin", {})}
    out["faults"] = {**{k: 0 for k in _sub(last, "faults")}, **_sub(doc, "faults")}
    for name in ("checkpoint", "terrain_check", "retask", "pins"):
        if name not in doc and name in last:
            out[name] = last[name]
    return out


def decode_status(payload: bytes, key: str = "status",
                  vehicle_id: str | None = None) -> dict[str, Any]:
    """Parse and validate a status object: size (MAX_STATUS_BYTES), strict JSON, schema
    and version, then every field a receiver reads, with its type and range
    (docs/protocol.md "status", "Validation and bounds"); ``vehicle_id`` when given: the
    one in the key. A receiver may then trust each field's type. Raises BusPayloadError
    naming ``key`` and the field (its ``reason`` says why, for counting)."""
    bad = Refuser(f"{key}: not a usable status")
    doc = json_object(payload, MAX_STATUS_BYTES, bad)
    check_schema(doc, STATUS_SCHEMA, STATUS_VERSION, bad)
    f = Fields(doc, bad)
    f.vehicle_id("vehicle_id", vehicle_id)
    f.integer("seq", 0, _U64)
    f.number("uptime_s", 0.0)
    f.number_or_null("t_s")
    thresholds = {float(t) for i, t in enumerate(f.items("thresholds", MAX_THRESHOLDS))
                  if _probability(t, f"thresholds[{i}]", bad)}
    if not thresholds:
        raise bad("thresholds: expected at least one P_D threshold")
    props = f.obj("proportion_at_or_above")
    if len(props.doc) > MAX_THRESHOLDS:
        raise bad(f"proportion_at_or_above: {len(props.doc)} entries, more than "
                  f"{MAX_THRESHOLDS}", Refusal.OVER_BOUND)
    for name in props.doc:
        if _threshold_key(name) not in thresholds:
            raise bad(f"proportion_at_or_above.{name[:40]}: the key is not one of the "
                      "thresholds written as a number (\"0.8\")")
        props.number(name, 0.0, 1.0)
    f.number("mean_pd", 0.0, 1.0)
    f.number("expected_false_alarms", 0.0)
    grid = _check_grid(f.obj("grid"), bad)
    cells_free = f.integer("cells_free", 0, grid)
    f.integer("cells_observed", 0, cells_free)
    frames = f.obj("frames")
    frames.integer("used", 0, _U32)
    frames.integer_or_null("grid", 0, _U32)
    frames.integer_or_null("pending", 0, _U32)
    frames.counts("skipped", MAX_NAMED_COUNTS, _U64)
    if "by_camera" in frames.doc:  # a cameras list only
        frames.counts("by_camera", MAX_NAMED_COUNTS, _U32)
    frames.string_or_null("source")
    frames.number_or_null("last_t_s")
    link = f.obj("link")
    link.string_or_null("state", max_len=40)
    link.number_or_null("last_message_age_s", 0.0)
    link.integer_or_null("messages", 0, _U64)
    link.integer_or_null("bad_messages", 0, _U64)
    pose = f.obj_or_null("pose")
    if pose is not None:
        pose.number("lat_deg", -90.0, 90.0)
        pose.number("lon_deg", -180.0, 360.0)
        pose.number_or_null("alt_msl_m", -1e4, 1e5)
        pose.number_or_null("heading_deg", -360.0, 360.0)
        pose.number_or_null("t_s")
        pose.number_or_null("gnss_h_acc_m", 0.0, MAX_GNSS_ACCURACY_M)  # absent: older daemon
    gimbal = f.obj("gimbal")
    for name in ("mount", "interpretation"):
        gimbal.string_or_null(name, max_len=40)
    gimbal.string_or_null("describe", max_len=500)
    f.integer("tiles_seq", -1, _U64)
    f.counts("faults", MAX_NAMED_COUNTS, _U64)
    f.obj_or_null("checkpoint")
    f.boolean_or_null("full")
    terrain = f.obj_or_null("terrain_check")  # absent: no DEM, or an older daemon
    if terrain is not None:
        _check_terrain(terrain)
    retask = f.obj_or_null("retask")  # absent: no re-tasking request yet, or an older daemon
    if retask is not None:
        retask.boolean_or_null("enabled")
        retask.boolean_or_null("uploading")
        retask.counts("refused", MAX_NAMED_COUNTS, _U64)
        last = retask.obj_or_null("last")
        if last is not None:
            last.string("plan_hash", max_len=16)
            last.string_or_null("key_id", max_len=16)  # absent: a daemon before signing
            last.boolean_or_null("accepted")
            last.string("result", max_len=64)
            last.integer("items", 0, _U32)
    pins = f.obj_or_null("pins")  # absent: an older daemon
    if pins is not None:
        _check_pins(pins)
    return doc


def _check_pins(p: Fields) -> None:
    """Check the status's ``pins`` (docs/protocol.md)."""
    n = p.integer("candidates", 0, _U32)
    p.integer("likely", 0, n)
    top = p.obj_or_null("top")
    if top is not None:
        uid = top.doc.get("uid")
        if not valid_uid(uid):
            raise top.bad(f"{top.where}uid {str(uid)[:120]!r}: expected {UID_RULE}")
        top.number("p_person", 0.0, 1.0)
        looks = top.integer("looks", 0, _U32)
        top.integer("hits", 0, looks)


MAX_TERRAIN_DIFFERENCE_M = 1e5


def _check_terrain(t: Fields) -> None:
    """Check the status's ``terrain_check`` (docs/protocol.md)."""
    t.number("margin_m", 0.0, MAX_TERRAIN_DIFFERENCE_M)
    t.counts("checked", MAX_NAMED_COUNTS, _U64)
    t.integer("mismatches", 0, _U64)
    t.counts("refused", MAX_NAMED_COUNTS, _U64)
    for name in ("largest", "latest"):
        m = t.obj_or_null(name)
        if m is not None:
            m.string("source", max_len=40)
            m.number("difference_m", -MAX_TERRAIN_DIFFERENCE_M, MAX_TERRAIN_DIFFERENCE_M)
            m.number("lat_deg", -90.0, 90.0)
            m.number("lon_deg", -180.0, 360.0)
            m.number_or_null("t_s")


def _check_grid(g: Fields, bad: Refuser) -> int:
    """Check the status's grid description; returns its number of cells."""
    g.string("hash", GRID_HASH)
    for name in ("x0_m", "y0_m"):
        g.number(name, -MAX_ENU_M, MAX_ENU_M)
    if not g.number("cell_size_m") > 0:
        raise bad("grid.cell_size_m: expected a positive number of metres")
    n_rows = g.integer("n_rows", 1, MAX_GRID_CELLS)
    n_cols = g.integer("n_cols", 1, MAX_GRID_CELLS)
    if n_rows * n_cols > MAX_GRID_CELLS:
        raise bad(f"grid: {n_rows} x {n_cols} cells: at most MAX_GRID_CELLS {MAX_GRID_CELLS}",
                  Refusal.OVER_BOUND)
    g.integer("tile_size", 1, MAX_TILE_SIZE)
    origin = g.obj("origin")
    if origin.doc:  # {} in a brief status
        origin.number("lat_deg", -90.0, 90.0)
        origin.number("lon_deg", -180.0, 360.0)
        origin.number_or_null("ground_alt_msl_m", -1e4, 1e5)
        origin.string_or_null("how")
    return n_rows * n_cols


def _probability(v: Any, name: str, bad: Refuser) -> bool:
    if not (is_number(v) and 0 <= v <= 1):
        raise bad(f"{name}: expected a P_D threshold in [0, 1], got {v!r}"[:200])
    return True


def _threshold_key(name: str) -> float | None:
    """The threshold a proportion_at_or_above key names ("0.8"), or None."""
    try:
        return float(name) if len(name) <= 40 else None
    except ValueError:
        return None
