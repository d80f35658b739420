"""The frames payload an onboard detector publishes on ``pdcov/<id>/frames`` (docs/protocol.md
"frames"): UTF-8 JSON, in two versions, both read.

Version 1, the frame times only::

    {"schema": "pdcov.frames", "version": 1, "t_boot_s": [t, ...]}

Version 2, each frame's time and the boxes the detector found in it::

    {"schema": "pdcov.frames", "version": 2,
     "frames": [{"t_boot_s": t, "boxes": [{"class": "person", "confidence": 0.87,
                                           "box_px": [left, top, width, height]}]}]}

(optionally with ``"vehicle": id``, then checked against the key's vehicle).

Times are seconds of the autopilot's boot clock (time_boot_ms / 1000); boxes are in image
pixels, OpenCV convention (core/detections.py). At most MAX_FRAMES frames per message and
MAX_BOXES_PER_FRAME boxes per frame. Whether a box lies inside the picture needs the camera:
``decode_frames`` checks it when given the picture's size.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from typing import Any

from pdcov.bus.errors import Refusal, Refuser
from pdcov.bus.json_doc import Fields, check_schema, is_number, json_object
from pdcov.core.detections import CLASS_NAME_RULE, Box, FrameBoxes, valid_class_name

__all__ = ["FRAMES_SCHEMA", "MAX_BOXES_PER_FRAME", "MAX_FRAMES", "MAX_FRAMES_BYTES",
           "VERSIONS", "decode_frames", "encode_frames", "encode_frames_v2"]

FRAMES_SCHEMA = "pdcov.frames"
VERSIONS = (1, 2)
MAX_FRAMES = 1000
"""Most frames per message (either version)."""
MAX_BOXES_PER_FRAME = 256
"""Most boxes per frame: more is a detector flooding the daemon (refused, ``over a bound``)."""
MAX_FRAMES_BYTES = 1 << 20
"""Largest frames payload accepted."""


def encode_frames(t_boot_s: Sequence[float]) -> bytes:
    """A version 1 frames message for the given frame times (autopilot boot clock, s)."""
    return json.dumps({"schema": FRAMES_SCHEMA, "version": 1,
                       "t_boot_s": [float(t) for t in t_boot_s]}).encode()


def encode_frames_v2(frames: Sequence[FrameBoxes]) -> bytes:
    """A version 2 frames message: each frame's time and boxes."""
    return json.dumps({"schema": FRAMES_SCHEMA, "version": 2, "frames": [
        {"t_boot_s": float(f.t_boot_s),
         "boxes": [{"class": b.class_name, "confidence": float(b.confidence),
                    "box_px": [float(v) for v in b.box_px]} for b in f.boxes]}
        for f in frames]}, separators=(",", ":"), allow_nan=False).encode()


def decode_frames(payload: bytes, key: str = "frames",
                  picture_px: tuple[int, int] | None = None,
                  vehicle_id: str | None = None) -> tuple[FrameBoxes, ...]:
    """The frames of a frames message of either version (version 1 frames have no boxes):
    1..MAX_FRAMES frames with times >= 0, each with at most MAX_BOXES_PER_FRAME boxes of a
    class name (CLASS_NAME_RULE), a confidence in [0, 1] and a finite box of positive width
    and height; with ``picture_px`` (width, height) every box inside that picture
    (Box.inside_picture); a version 2 message may name its ``vehicle`` (optional), which
    must then be ``vehicle_id`` when that is given (the key's). Raises BusPayloadError
    naming ``key``, the field and the reason; a message is taken whole or not at all."""
    bad = Refuser(f"{key}: not a usable frames message")
    doc = json_object(payload, MAX_FRAMES_BYTES, bad)
    version = check_schema(doc, FRAMES_SCHEMA, VERSIONS, bad)
    if version == 1:
        t = doc.get("t_boot_s")
        if (not isinstance(t, list) or not 1 <= len(t) <= MAX_FRAMES
                or not all(is_number(v) and v >= 0 for v in t)):
            raise bad(f"t_boot_s: expected a list of 1..{MAX_FRAMES} times >= 0 (s)",
                      Refusal.OVER_BOUND if isinstance(t, list) and len(t) > MAX_FRAMES
                      else Refusal.BAD_FIELD)
        return tuple(FrameBoxes(float(v)) for v in t)
    f = Fields(doc, bad)
    if doc.get("vehicle") is not None:
        f.vehicle_id("vehicle", vehicle_id)
    items = f.items("frames", MAX_FRAMES)
    if not items:
        raise bad(f"frames: expected 1..{MAX_FRAMES} frames, got none")
    return tuple(_frame(Fields(item, bad, f"frames[{i}]."), picture_px)
                 for i, item in enumerate(items))


def _frame(f: Fields, picture_px: tuple[int, int] | None) -> FrameBoxes:
    t_boot_s = f.number("t_boot_s", 0.0)
    boxes = f.items("boxes", MAX_BOXES_PER_FRAME)
    return FrameBoxes(t_boot_s, tuple(_box(Fields(b, f.bad, f"{f.where}boxes[{j}]."),
                                           picture_px) for j, b in enumerate(boxes)))


def _box(f: Fields, picture_px: tuple[int, int] | None) -> Box:
    name: Any = f.doc.get("class")
    if not valid_class_name(name):
        raise f.bad(f"{f.where}class {name!r}: expected {CLASS_NAME_RULE}"[:300])
    confidence = f.number("confidence", 0.0, 1.0)
    px: Any = f.doc.get("box_px")
    if not (isinstance(px, list) and len(px) == 4 and all(is_number(v) for v in px)):
        raise f.bad(f"{f.where}box_px: expected [left, top, width, height] (4 numbers, "
                    f"px), got {px!r}"[:300])
    if not (px[2] > 0 and px[3] > 0):
        raise f.bad(f"{f.where}box_px {px!r}: width and height must be > 0 px"[:300])
    # Interned: a flood of boxes then holds one string per class, not one per box.
    box = Box(sys.intern(name), confidence, *(float(v) for v in px))
    if picture_px is not None and not box.inside_picture(*picture_px):
        w, h = picture_px
        raise f.bad(f"{f.where}box_px {px!r}: outside the {w}x{h} px picture (it spans "
                    f"[-0.5, {w - 0.5:g}] x [-0.5, {h - 0.5:g}])"[:300], Refusal.OUTSIDE_PICTURE)
    return box
