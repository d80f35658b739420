"""Flight plans: waypoints in ENU with altitude above ground, speed and hover time, the
gimbal pointing and camera zoom commanded on the way to each, and the frame their altitudes
are written in. The MAVLink mission items a plan becomes (and is read back from):
plan_items.py; its files (QGroundControl ``.plan``, ``QGC WPL 110``): plan_files.py."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from pdcov.core.mission import AltitudeFrame, GimbalCommand, HoverItem, MissionItem

T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class GimbalPointing:
    """Where a gimbal points: pitch against the horizon (rad, -pi/2: nadir) and yaw (rad,
    clockwise) from the vehicle's heading, or from north when ``earth_yaw``."""

    pitch_rad: float
    yaw_rad: float = 0.0
    earth_yaw: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.pitch_rad) and math.isfinite(self.yaw_rad)):
            raise ValueError(f"gimbal pointing must be finite, got {self}")

    def item(self, command: GimbalCommand) -> MissionItem:
        """The mission item commanding it; yaw written in (-180, 180] deg."""
        yaw_deg = math.degrees(math.remainder(self.yaw_rad, 2 * math.pi))
        return command.item(math.degrees(self.pitch_rad), yaw_deg, self.earth_yaw)


@dataclass(frozen=True, slots=True)
class Waypoint:
    """One waypoint: ENU metres, altitude above ground (m; above the terrain when the plan
    follows it), speed to fly towards it (m/s), and the time to hover on reaching it (s).

    z_enu_m: ENU height of the path at the waypoint (m; default ``alt_agl_m``: the flat
    ground z = 0). terrain_added: a point added along a leg to follow the terrain, not a
    turn of the pattern (a MAV_FRAME_GLOBAL_TERRAIN_ALT mission leaves it out). gimbal:
    the pointing commanded on leaving the previous waypoint, held on the way here and
    while here (None: the one in force). zoom_hfov_deg: the camera's zoom commanded there
    too, as a horizontal field of view (deg; None: the one in force, at first the
    configured camera)."""

    x_enu_m: float
    y_enu_m: float
    alt_agl_m: float
    speed_mps: float
    hover_s: float = 0.0
    z_enu_m: float = math.nan
    terrain_added: bool = False
    gimbal: GimbalPointing | None = None
    zoom_hfov_deg: float | None = None

    def __post_init__(self) -> None:
        if math.isnan(self.z_enu_m):
            object.__setattr__(self, "z_enu_m", self.alt_agl_m)
        if not all(math.isfinite(v) for v in (self.x_enu_m, self.y_enu_m, self.alt_agl_m,
                                              self.z_enu_m)):
            raise ValueError(f"waypoint position must be finite, got {self}")
        if not self.alt_agl_m > 0:
            raise ValueError(f"alt_agl_m must be > 0 m, got {self.alt_agl_m}")
        if not (self.speed_mps > 0 and math.isfinite(self.speed_mps)):
            raise ValueError(f"speed_mps must be > 0, got {self.speed_mps}")
        if not (self.hover_s >= 0 and math.isfinite(self.hover_s)):
            raise ValueError(f"hover_s must be >= 0 s, got {self.hover_s}")
        if self.zoom_hfov_deg is not None and not 0 < self.zoom_hfov_deg < 180:
            raise ValueError(f"zoom_hfov_deg must be in (0, 180) deg, got {self.zoom_hfov_deg}")


@dataclass(frozen=True, slots=True)
class Plan:
    """An ordered list of waypoints, a one-line description of how it was made, and the
    frame its altitudes are written in (RELATIVE: the flat ground, or a constant altitude
    above home). gimbal_command: the item the waypoints' gimbal pointings are written as.
    hover_item: how hovers are written. zoom_not_predicted: a plan read from a mission
    with a zoom item of another type than the field of view, that item ('' none:
    plan_items.py)."""

    waypoints: tuple[Waypoint, ...]
    description: str = ""
    altitude_frame: AltitudeFrame = AltitudeFrame.RELATIVE
    gimbal_command: GimbalCommand = GimbalCommand.MANAGER
    hover_item: HoverItem = HoverItem.WAYPOINT
    zoom_not_predicted: str = ""

    def __post_init__(self) -> None:
        if len(self.waypoints) < 1:
            raise ValueError("a plan needs at least one waypoint")

    @property
    def xy_enu_m(self) -> np.ndarray:
        """(N, 2) waypoint positions, ENU metres."""
        return np.array([[w.x_enu_m, w.y_enu_m] for w in self.waypoints], dtype=float)

    @property
    def path_length_m(self) -> float:
        """Length of the polyline through the waypoints in 3-D, metres."""
        return float(np.linalg.norm(np.diff(self.xyz_enu_m, axis=0), axis=1).sum())

    @property
    def xyz_enu_m(self) -> np.ndarray:
        """(N, 3) waypoint positions with the path's height (z_enu_m), ENU metres."""
        return np.array([[w.x_enu_m, w.y_enu_m, w.z_enu_m] for w in self.waypoints],
                        dtype=float)

    def pointings(self) -> list[GimbalPointing | None]:
        """Per waypoint, the gimbal pointing in force on the way to it and at it (None:
        before any is commanded)."""
        return _held([w.gimbal for w in self.waypoints])

    def zooms_hfov_deg(self) -> list[float | None]:
        """Per waypoint, the camera zoom (horizontal field of view, deg) in force on the way
        to it and at it (None: before any is commanded, the configured camera)."""
        return _held([w.zoom_hfov_deg for w in self.waypoints])

    def written(self) -> np.ndarray:
        """bool (N,): the waypoints a mission carries; a MAV_FRAME_GLOBAL_TERRAIN_ALT one
        leaves out the points added along the terrain."""
        return np.array([not (w.terrain_added
                              and self.altitude_frame is AltitudeFrame.TERRAIN_ALT)
                         for w in self.waypoints], dtype=bool)

    @classmethod
    def from_xy(cls, xy_enu_m: np.ndarray, alt_agl_m: float, speed_mps: float,
                description: str = "") -> Plan:
        """A plan at one altitude and speed through (N, 2) ENU points; repeated points are
        dropped."""
        pts = np.asarray(xy_enu_m, dtype=float).reshape(-1, 2)
        keep = np.ones(len(pts), dtype=bool)
        keep[1:] = np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-6
        return cls(tuple(Waypoint(float(x), float(y), alt_agl_m, speed_mps)
                         for x, y in pts[keep]), description)


def _held(commanded: list[T | None]) -> list[T | None]:
    """Per waypoint, what a mission item commanded there or before it is in force (None:
    nothing yet): each value, or the last one given before it."""
    out: list[T | None] = []
    now: T | None = None
    for value in commanded:
        now = now if value is None else value
        out.append(now)
    return out
