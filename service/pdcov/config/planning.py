"""The mission config's ``planning`` section (read by ``pdcov plan``): the flight
kinematics of a prediction and how plans follow the terrain."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pdcov.config.values import defaults
from pdcov.core.mission import AltitudeFrame
from pdcov.errors import ConfigError, where


@dataclass(frozen=True, slots=True)
class PlanningSection:
    """``planning`` (read by ``pdcov plan`` only): the flight kinematics of the prediction
    (planning.trajectory.Kinematics: m/s^2, deg/s, tilt, m, the gimbal's slew rate deg/s),
    the gimbal pitch (deg), and
    how plans meet the terrain (planning.terrain_follow.TerrainFollowing): the frame
    (None: amsl with a terrain, relative without), tolerance (m), climb and descent rates
    (m/s; 0: no limit) and clearance (m)."""

    max_accel_mps2: float = 2.5
    max_yaw_rate_deg_s: float = 60.0
    tilt: bool = True
    corner_cut_m: float = 2.0
    gimbal_rate_deg_s: float = 90.0
    gimbal_pitch_deg: float = -90.0
    terrain_frame: AltitudeFrame | None = None
    terrain_tolerance_m: float = 2.0
    terrain_max_climb_mps: float = 2.5
    terrain_max_descent_mps: float = 1.5
    terrain_clearance_m: float = 10.0

    @classmethod
    def from_mapping(cls, doc: Any, src: str | None) -> PlanningSection:
        """From the section (None: the defaults); ConfigError naming ``planning``."""
        doc = doc or {}
        if not isinstance(doc, Mapping):
            raise ConfigError(f"{where(src, 'planning')}: expected a mapping, got {doc!r}")
        given = {**defaults(cls), **doc}
        frame = given["terrain_frame"]
        if frame is not None and frame not in set(AltitudeFrame):
            raise ConfigError(f"{where(src, 'planning.terrain_frame')}: expected one of "
                              f"{', '.join(AltitudeFrame)}, got {frame!r}")
        try:
            return cls(float(given["max_accel_mps2"]), float(given["max_yaw_rate_deg_s"]),
                       bool(given["tilt"]), float(given["corner_cut_m"]),
                       float(given["gimbal_rate_deg_s"]), float(given["gimbal_pitch_deg"]),
                       None if frame is None else AltitudeFrame(frame),
                       *(float(given[k]) for k in (
                           "terrain_tolerance_m", "terrain_max_climb_mps",
                           "terrain_max_descent_mps", "terrain_clearance_m")))
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{where(src, 'planning')}: {exc}") from None
