"""What an object detector reports and what pdcov makes of it: boxes per frame, geolocated
detections, and candidates (detections of one target grouped across frames).

Pixels follow OpenCV: pixel centres at integers, so a picture ``width_px`` wide spans
x in [-0.5, width_px - 0.5) (core/camera.py ``in_picture``). A box is its left and top
edges and its size, in those pixels. Times are the autopilot's boot clock
(time_boot_ms / 1000, s), as the frames they belong to. Positions are local ENU metres
about the mission's origin (DESIGN.md).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

__all__ = ["CLASS_NAME_RULE", "UID_RULE", "Box", "Candidate", "Detection", "FrameBoxes",
           "valid_class_name", "valid_uid"]

CLASS_NAME_RULE = ("1 to 64 printable ASCII characters, words separated by single spaces "
                   "(no leading or trailing space)")
_CLASS_NAME = re.compile(r"[!-~]+(?: [!-~]+)*")
_CLASS_NAME_MAX = 64
UID_RULE = "1 to 100 characters of A-Z, a-z, 0-9, '.', '_', '-'"
_UID = re.compile(r"[A-Za-z0-9._-]{1,100}")


def valid_class_name(name: object) -> bool:
    """True for a detector class name pdcov carries (CLASS_NAME_RULE): printable, so that
    it fits a log line and the recording's box marks (telemetry/recorded_frames.py)."""
    return (isinstance(name, str) and len(name) <= _CLASS_NAME_MAX
            and _CLASS_NAME.fullmatch(name) is not None)


def valid_uid(uid: object) -> bool:
    """True for a candidate uid (UID_RULE): it names the pin on the bus, in CoT and files."""
    return isinstance(uid, str) and _UID.fullmatch(uid) is not None


def _finite(*values: float) -> bool:
    return all(isinstance(v, (int, float)) and math.isfinite(v) for v in values)


@dataclass(frozen=True, slots=True)
class Box:
    """One detector box in image pixels (module docstring): ``class_name``
    (CLASS_NAME_RULE), ``confidence`` in [0, 1], left and top edges, and a positive width
    and height."""

    class_name: str
    confidence: float
    left_px: float
    top_px: float
    width_px: float
    height_px: float

    def __post_init__(self) -> None:
        if not valid_class_name(self.class_name):
            raise ValueError(f"box class_name {self.class_name!r}: expected {CLASS_NAME_RULE}")
        if not (_finite(self.confidence) and 0.0 <= self.confidence <= 1.0):
            raise ValueError(f"box confidence {self.confidence!r}: expected a number in [0, 1]")
        if not _finite(self.left_px, self.top_px, self.width_px, self.height_px):
            raise ValueError(f"box {self.box_px}: expected finite pixel coordinates")
        if not (self.width_px > 0 and self.height_px > 0):
            raise ValueError(f"box {self.box_px}: width and height must be > 0 px")

    @property
    def box_px(self) -> tuple[float, float, float, float]:
        """(left, top, width, height) in pixels, as the frames payload carries them."""
        return (self.left_px, self.top_px, self.width_px, self.height_px)

    @property
    def centre_px(self) -> tuple[float, float]:
        """The box's centre (x, y) in pixels."""
        return (self.left_px + 0.5 * self.width_px, self.top_px + 0.5 * self.height_px)

    @property
    def bottom_centre_px(self) -> tuple[float, float]:
        """The middle of the box's bottom edge (x, y) in pixels: a standing person's feet."""
        return (self.left_px + 0.5 * self.width_px, self.top_px + self.height_px)

    def inside_picture(self, width_px: int, height_px: int) -> bool:
        """True when the whole box lies in a picture of this size, [-0.5, width_px - 0.5] x
        [-0.5, height_px - 0.5] (a box may reach the picture's far edges)."""
        return (self.left_px >= -0.5 and self.top_px >= -0.5
                and self.left_px + self.width_px <= width_px - 0.5
                and self.top_px + self.height_px <= height_px - 0.5)


@dataclass(frozen=True, slots=True)
class FrameBoxes:
    """One detector frame: its time ``t_boot_s`` (autopilot boot clock, s, >= 0) and the
    boxes the detector found in it (none is a frame it processed and found nothing in)."""

    t_boot_s: float
    boxes: tuple[Box, ...] = ()

    def __post_init__(self) -> None:
        if not (_finite(self.t_boot_s) and self.t_boot_s >= 0):
            raise ValueError(f"frame t_boot_s {self.t_boot_s!r}: expected a time >= 0 (s)")
        boxes = tuple(self.boxes)
        if not all(isinstance(b, Box) for b in boxes):
            raise ValueError("frame boxes: expected Box values")
        object.__setattr__(self, "boxes", boxes)


def _point_enu(r: np.ndarray, name: str) -> np.ndarray:
    """``r`` as a read-only float64 (3,) of finite ENU metres."""
    p = np.array(r, dtype=np.float64).reshape(-1)
    if p.shape != (3,) or not np.isfinite(p).all():
        raise ValueError(f"{name}: expected 3 finite ENU metres, got {r!r}")
    p.setflags(write=False)
    return p


def _check_sigma(sigma_m: float, what: str) -> None:
    if not (_finite(sigma_m) and sigma_m >= 0):
        raise ValueError(f"{what} sigma_m {sigma_m!r}: expected a finite number >= 0 (m)")


@dataclass(frozen=True, slots=True)
class Detection:
    """One geolocated box: the frame's time ``t_boot_s``, the ``box``, its ground point
    ``r_enu_m`` (3,) (ENU m, read-only), ``sigma_m`` the 1-sigma horizontal uncertainty of
    that point (m; core/geolocate.py says how it is computed), the ``candidate_id`` it
    was grouped into and the frame's UTC ``unix_s`` (s since 1970; NaN: unknown)."""

    t_boot_s: float
    box: Box
    r_enu_m: np.ndarray
    sigma_m: float
    candidate_id: int
    unix_s: float = math.nan

    def __post_init__(self) -> None:
        if not (_finite(self.t_boot_s) and self.t_boot_s >= 0):
            raise ValueError(f"detection t_boot_s {self.t_boot_s!r}: expected a time >= 0 (s)")
        object.__setattr__(self, "r_enu_m", _point_enu(self.r_enu_m, "detection r_enu_m"))
        _check_sigma(self.sigma_m, "detection")
        if not (isinstance(self.candidate_id, int) and self.candidate_id >= 0):
            raise ValueError(f"detection candidate_id {self.candidate_id!r}: expected an "
                             "integer >= 0")


@dataclass(frozen=True, slots=True)
class Candidate:
    """Detections of one target grouped across frames (detection/candidates.py).

    candidate_id: >= 0, unique in a flight. class_name: the detections' class.
    r_enu_m (3,): the inverse-variance weighted mean of their ground points (ENU m).
    sigma_m: its 1-sigma horizontal uncertainty (m). looks: the counted looks of its cell
    (the grid's revisit clock); hits: those of them with a box in its gate (<= looks).
    pd, pfa: the cell's cumulative P_D and P_FA. uid: unique across restarts and vehicles
    (UID_RULE). p_person: the probability that a person is within its gate. confidence:
    the best detection's. first_t_boot_s, last_t_boot_s: its first and last detection
    (autopilot boot clock, s); first_unix_s, last_unix_s: the same in UTC (s since 1970;
    NaN: unknown).
    """

    candidate_id: int
    class_name: str
    r_enu_m: np.ndarray
    sigma_m: float
    hits: int
    looks: int
    pd: float
    pfa: float
    confidence: float
    first_t_boot_s: float
    last_t_boot_s: float
    uid: str
    p_person: float
    first_unix_s: float = math.nan
    last_unix_s: float = math.nan

    def __post_init__(self) -> None:
        if not valid_uid(self.uid):
            raise ValueError(f"candidate uid {self.uid!r}: expected {UID_RULE}")
        if not (isinstance(self.candidate_id, int) and self.candidate_id >= 0):
            raise ValueError(f"candidate_id {self.candidate_id!r}: expected an integer >= 0")
        if not valid_class_name(self.class_name):
            raise ValueError(f"candidate class_name {self.class_name!r}: expected "
                             f"{CLASS_NAME_RULE}")
        object.__setattr__(self, "r_enu_m", _point_enu(self.r_enu_m, "candidate r_enu_m"))
        _check_sigma(self.sigma_m, "candidate")
        for name in ("hits", "looks"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 0):
                raise ValueError(f"candidate {name} {v!r}: expected an integer >= 0")
        if self.hits > self.looks:
            raise ValueError(f"candidate hits {self.hits}: more than its looks {self.looks} "
                             "(at most one hit per look)")
        for name in ("pd", "pfa", "confidence", "p_person"):
            v = getattr(self, name)
            if not (_finite(v) and 0.0 <= v <= 1.0):
                raise ValueError(f"candidate {name} {v!r}: expected a number in [0, 1]")
        if not (_finite(self.first_t_boot_s, self.last_t_boot_s)
                and 0 <= self.first_t_boot_s <= self.last_t_boot_s):
            raise ValueError(f"candidate first_t_boot_s {self.first_t_boot_s!r}, "
                             f"last_t_boot_s {self.last_t_boot_s!r}: expected 0 <= first "
                             "<= last (s)")
