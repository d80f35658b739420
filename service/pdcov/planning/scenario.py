"""The prediction inputs of a mission (``scenario_of``) and the bound on a plan's size that
every planning command and the ground station's re-fly apply (``check_plan_size``).

The mission config's optional ``planning`` section (docs/planning.md) sets the vehicle's
kinematic limits and how plans meet the terrain; ``overrides`` are the same keys given on
the command line.
"""

from __future__ import annotations

import math
import sys
from typing import Any

from pdcov.config.mission import Mission
from pdcov.config.planning import PlanningSection
from pdcov.core.mission import AltitudeFrame
from pdcov.errors import ConfigError, where
from pdcov.planning.optimise import Scenario
from pdcov.planning.terrain_follow import TerrainFollowing
from pdcov.planning.trajectory import Kinematics


def scenario_of(mission: Mission, overrides: dict[str, Any] | None = None) -> Scenario:
    """The prediction inputs of a mission, with its ``planning`` section applied and then
    ``overrides`` (planning keys given on the command line). Plans fly over the mission's
    ``flight_domain`` (the domain as configured: over roofs too) and are scored on the
    searched ``domain``'s free cells (the grids' free mask: without the roofs)."""
    doc = mission.raw.get("planning")
    if overrides and (doc is None or isinstance(doc, dict)):  # else from_mapping refuses it
        doc = {**(doc or {}), **overrides}
    cfg = PlanningSection.from_mapping(doc, mission.source)
    frame = cfg.terrain_frame or (AltitudeFrame.RELATIVE if mission.terrain is None
                                  else AltitudeFrame.AMSL)
    if mission.terrain is None and frame is not AltitudeFrame.RELATIVE:
        raise ConfigError(f"{where(mission.source, 'planning.terrain_frame')}: {frame} "
                          "follows the terrain, but the mission has none (add terrain.dem, "
                          "or use relative)")
    if frame is AltitudeFrame.AMSL and mission.ground_alt_msl_m is None:
        raise ConfigError(f"{where(mission.source, 'origin.ground_alt_msl_m')}: missing; "
                          "amsl waypoints are written above mean sea level from it")
    try:
        kin = Kinematics(cfg.max_accel_mps2, math.radians(cfg.max_yaw_rate_deg_s), cfg.tilt,
                         cfg.corner_cut_m, math.radians(cfg.gimbal_rate_deg_s))
        following = TerrainFollowing(frame, cfg.terrain_tolerance_m, cfg.terrain_max_climb_mps,
                                     cfg.terrain_max_descent_mps, cfg.terrain_clearance_m)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where(mission.source, 'planning')}: {exc}") from None
    pitch = math.radians(cfg.gimbal_pitch_deg)
    searched = mission.domain
    g = searched.grid_geometry(mission.cell_size_m)  # the flight domain's too: one boundary
    cam = mission.first_camera  # the planner flies one camera
    return Scenario(mission.flight_domain.free_space, g, searched.free_mask(g), cam.camera,
                    cam.detector, cam.mount, cam.frame_rate_hz,
                    mission.max_range_m, mission.min_revisit_s, kin, pitch, mission.terrain,
                    following, cam.exposure_s, mission.looks, cam.zoom)


# Refused above this many predicted camera frames (the flight is sampled at the camera's
# frame rate); warned above this flight time.
MAX_PLAN_FRAMES = 20_000_000
LONG_FLIGHT_S = 4 * 3600.0


def check_plan_size(sc: Scenario, spacing_m: float, speed_mps: float) -> None:
    """Estimate a sweep's path (free area / spacing) before building it: refuse a plan of
    more than MAX_PLAN_FRAMES frames with the figures, warn about one over LONG_FLIGHT_S."""
    path_m = sc.free_space.area / spacing_m
    flight_s = path_m / speed_mps
    frames = flight_s * sc.frame_rate_hz
    what = (f"track spacing {spacing_m:g} m over {sc.free_space.area:,.0f} m^2 gives about "
            f"{path_m / 1000:,.1f} km of track, {flight_s / 3600:,.1f} h of flight at "
            f"{speed_mps:g} m/s and {frames:,.0f} camera frames")
    if frames > MAX_PLAN_FRAMES:
        raise ConfigError(f"{what}; at most {MAX_PLAN_FRAMES:,} frames are predicted: "
                          "widen --spacing-m (or lower --overlap) or split the domain")
    if flight_s > LONG_FLIGHT_S:
        print(f"WARNING: {what}: far beyond one battery; check --spacing-m, --overlap and "
              "--speed-mps", file=sys.stderr)
