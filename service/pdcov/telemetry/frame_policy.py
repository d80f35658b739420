"""The frame rules the live daemon and ``pdcov evaluate`` share, each written once.

Both drivers call these functions (DESIGN.md "one pipeline, two drivers"), so that a live
grid equals the offline grid of the same telemetry because the code is the same, not
because two copies are kept equal:

* where frames go: ``FrameSource`` and the rate ``FrameLattice`` (t0 + k / rate from the
  first time every needed stream has samples);
* whose samples count: ``AUTOPILOT_ONLY``;
* which attitude messages count: ``AttitudeSource`` (ATTITUDE once the autopilot sends it,
  ATTITUDE_QUATERNION only before);
* which frames are used: ``untrusted_policy`` / ``frames_used`` (valid, and trusted unless
  the mount says to use untrusted ones);
* the pose a frame is evaluated with: ``rebuilt_R_enu_cam`` (rebuilt from its quaternion,
  so that a pose CSV reads back bit-identical and both drivers add the same rotation);
* which frames are evaluated: ``below_min_height``;
* the ENU origin's ground altitude: ``home_ground_alt`` and ``position_ground_alt``;
* the reasons a frame is skipped: ``SkipReason``;
* the camera a frame is evaluated with: ``frame_cameras`` (the zoom report in force,
  lens_reports.py, through the mission's zoom lens, core/zoom.py).

Pure: numpy and the core only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Literal

import numpy as np

from pdcov.core.camera import CameraModel
from pdcov.core.mount import GimbalMount
from pdcov.core.pose import FixedMount
from pdcov.core.rotations import R_from_quat_wxyz, quat_wxyz_from_R
from pdcov.core.zoom import Zoom
from pdcov.telemetry.samples import (
    AttitudeSample,
    EstimatorSample,
    GnssAccuracySample,
    HomeSample,
    ParamSample,
    PositionSample,
    RangefinderSample,
    TerrainReportSample,
    UtcSample,
)


class TextEnum(str, Enum):
    """A flag that is also its text: compares equal to the string, prints and encodes to
    JSON as it."""

    def __str__(self) -> str:
        return str(self.value)


class FrameSource(TextEnum):
    """Where frame times come from: every 1/rate s, the autopilot's capture events, or a
    detector's frames over Zenoh (live; recorded, so offline reads them as captures)."""

    RATE = "rate"
    CAPTURE = "capture"
    ZENOH = "zenoh"


class SkipReason(TextEnum):
    """Why a frame was not added, as both drivers count it (the status's
    ``frames.skipped``, the evaluate summary). ``PoseTracker.frames_at`` also gives
    'outside the <stream> samples', '<stream> gap' and the estimator's reasons."""

    ATTITUDE_GAP = "attitude gap"
    POSITION_JUMP = "position jump"
    BELOW_MIN_HEIGHT = "below min height"
    LATE_FRAME_TIME = "late frame time"
    ZOOM_MISSING = "no camera zoom report"
    ZOOM_STALE = "camera zoom report stale"
    ZOOM_OUT_OF_RANGE = "camera zoom outside calibration"
    ZOOM_JUMP = "camera zoom jump"
    HOME_OFF_DEM = "home off the DEM"
    """The DEM is refused: the home is beyond terrain.max_home_offset_m from it
    (terrain_check.py)."""


AUTOPILOT_ONLY = (AttitudeSample, PositionSample, ParamSample, EstimatorSample,
                  TerrainReportSample, RangefinderSample, GnssAccuracySample, UtcSample)
"""Samples taken from the autopilot component only, live and offline: the vehicle's
attitude, position, parameters, estimator, terrain database, rangefinder, GNSS accuracy
and real-time clock are the autopilot's own (a companion computer or an OSD of the same
system may send ATTITUDE or GLOBAL_POSITION_INT too); gimbal, home and capture reports
come from any component of the vehicle's system."""

UNTRUSTED_PREFIX = "gimbal untrusted: "
"""The live count of an untrusted frame skipped: this prefix and its reason."""


@dataclass(frozen=True, slots=True)
class FrameLattice:
    """Frames every 1/rate_hz s from t0_s (autopilot clock, s): frame k at
    ``t0_s + k / rate_hz``, computed so in both drivers (the same float operations give
    the same times to the last bit)."""

    t0_s: float
    rate_hz: float

    def t(self, k: int) -> float:
        return self.t0_s + k / self.rate_hz

    def times(self, n: int) -> np.ndarray:
        """The first ``n`` frame times (n,)."""
        return self.t0_s + np.arange(n) / self.rate_hz

    def count_until(self, t1_s: float) -> int:
        """How many frames lie at or before ``t1_s`` (from frame 0 on)."""
        return int(math.floor((t1_s - self.t0_s) * self.rate_hz + 1e-9)) + 1

    def first_at_or_after(self, t_s: float) -> int:
        """The index of the first frame at or after ``t_s``."""
        return math.ceil((t_s - self.t0_s) * self.rate_hz)


class AttitudeSource:
    """Which attitude messages of the autopilot count: ATTITUDE_QUATERNION until its first
    ATTITUDE, ATTITUDE from then on (the two interleaved would interpolate between them).
    Fed the autopilot's attitude messages in arrival (log) order: the link's causal rule,
    which the tlog reader applies to the log's messages in order, so that a log or link
    starting between the two messages of one attitude gives both the same samples."""

    __slots__ = ("euler",)

    def __init__(self) -> None:
        self.euler = False

    def takes(self, mtype: str) -> bool:
        """Whether the message of type ``mtype`` (ATTITUDE or ATTITUDE_QUATERNION) counts."""
        if mtype == "ATTITUDE":
            self.euler = True
            return True
        return not self.euler


UntrustedPolicy = Literal["use", "skip"]


def untrusted_policy(mount: FixedMount | GimbalMount) -> UntrustedPolicy:
    """'use' or 'skip' for frames whose camera direction is not trusted (mount.untrusted,
    which the config checks is one of the two; a fixed mount is always trusted: 'use')."""
    if isinstance(mount, GimbalMount) and mount.untrusted != "use":
        return "skip"
    return "use"


def frames_used(valid: np.ndarray, trusted: np.ndarray, policy: UntrustedPolicy
                ) -> np.ndarray:
    """The frames added: valid (every stream brackets them), and trusted unless the policy
    uses untrusted frames too."""
    return valid & (trusted | (policy == "use"))


def rebuilt_R_enu_cam(R_enu_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(q_enu_cam_wxyz (N, 4), R_enu_cam (N, 3, 3)): the camera rotations (N, 3, 3) rebuilt
    from their own quaternions, as both drivers evaluate them (a pose CSV written from the
    quaternions reads back to bit-identical rotations)."""
    q = quat_wxyz_from_R(R_enu_cam).reshape(-1, 4)
    return q, R_from_quat_wxyz(q).reshape(-1, 3, 3)


def below_min_height(z_enu_m: float | np.ndarray, min_height_m: float) -> bool | np.ndarray:
    """Camera heights (ENU z, m above the origin's ground) below coverage.min_height_m: on
    the ground or taking off, not evaluated."""
    return z_enu_m < min_height_m


HOME_SOURCES = ("HOME_POSITION", "ORGN home", "home_position", "ORGN EKF origin")
"""The homes a ground altitude is read from, best first (MAVLink, DataFlash, ULog)."""
POSITION_GROUND = "the first position's altitude minus its height above home"


def home_ground_alt(homes: Sequence[HomeSample]) -> tuple[float, str] | None:
    """The ground altitude (m MSL) of the latest home of the best source among ``homes``
    (in time order) and how it was found, or None without a home of finite altitude."""
    for prefer in HOME_SOURCES:
        found = [h for h in homes if h.source == prefer and math.isfinite(h.alt_msl_m)]
        if found:
            return found[-1].alt_msl_m, (f"the autopilot's home altitude ({prefer}, last of "
                                         f"{len(found)})")
    return None


def position_ground_alt(alt_msl_m: float, relative_alt_m: float) -> tuple[float, str]:
    """The ground altitude (m MSL) from the first position with a height above home."""
    return float(alt_msl_m - relative_alt_m), POSITION_GROUND


def frame_cameras(zoom: Zoom | None, lens_value: np.ndarray) -> list[CameraModel | None]:
    """The camera of each used frame from the zoom report in force (FrameBatch.lens_value,
    accepted by lens_reports), or None (the mission's configured camera) without a zoom."""
    if zoom is None:
        return [None] * len(lens_value)
    return [zoom.lens.camera(float(v)) for v in lens_value]
