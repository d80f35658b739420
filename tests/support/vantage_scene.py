"""The vantage-point tests' scene: a 20 m square with an obstacle, the target P_D, the
cover settings (exact and greedy, nadir and oblique), and a plan pointing the gimbal at
earth-frame yaws."""

from __future__ import annotations

import math
from dataclasses import replace

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.geodesy import Origin
from pdcov.core.mission import HoverItem
from pdcov.core.pose import FixedMount
from pdcov.planning.optimise import Scenario
from pdcov.planning.plan import GimbalPointing, Plan, Waypoint
from pdcov.planning.vantage import VantageSettings

OBSTACLE = [(4, -4), (12, -4), (12, 5), (4, 5)]


TARGET_PD = 0.9


SETTINGS = VantageSettings(TARGET_PD, (8.0, 12.0), (1.0, 2.0), lattice_m=5.0,
                           exact_time_limit_s=10.0)


GREEDY = VantageSettings(TARGET_PD, (8.0, 12.0), (1.0, 2.0), lattice_m=8.0,
                         exact_time_limit_s=0.0)


ROUTING_S = 1.0


def scene(mount=None) -> Scenario:
    """40 x 30 m around home with an 8 x 9 m obstacle east of it, 1 m cells, a nadir 70 deg
    camera at 2 frames/s, the illustrative detector."""
    dom = Domain.from_enu([(-20, -15), (20, -15), (20, 15), (-20, 15)], [OBSTACLE])
    geo = dom.grid_geometry(1.0)
    return Scenario(dom.free_space, geo, dom.free_mask(geo), CameraModel.from_fov(640, 480, 70),
                    DetectorModel.illustrative(), mount or FixedMount(), frame_rate_hz=2.0)


OBLIQUE_SETTINGS = replace(SETTINGS, gimbal_pitches_deg=(-90.0, -60.0, -45.0), gimbal_yaws=8,
                           exact_time_limit_s=0.0)


ORIGIN = Origin(39.35, -76.33, 5.0)


OBLIQUE_A = GimbalPointing(math.radians(-45.0), math.radians(45.0), earth_yaw=True)


OBLIQUE_B = GimbalPointing(math.radians(-60.0), math.radians(225.0), earth_yaw=True)


def pointed_plan(hover_item: HoverItem) -> Plan:
    """Nadir to the first waypoint, then OBLIQUE_A for a corner and a hover, OBLIQUE_B for
    the last hover."""
    return Plan((Waypoint(5.0, 0.0, 10.0, 3.0, gimbal=GimbalPointing(-math.pi / 2)),
                 Waypoint(5.0, 8.0, 10.0, 3.0, gimbal=OBLIQUE_A),
                 Waypoint(-5.0, 8.0, 10.0, 3.0, hover_s=4.0, gimbal=OBLIQUE_A),
                 Waypoint(-5.0, -5.0, 12.0, 3.0, hover_s=2.0, gimbal=OBLIQUE_B)),
                hover_item=hover_item)


MISSION_YAML = """\
vehicle_id: vt
origin: {lat_deg: 39.35, lon_deg: -76.33, ground_alt_msl_m: 5.0}
domain:
  polygon_enu_m: [[-20, -15], [20, -15], [20, 15], [-20, 15]]
  obstacles_enu_m: [[[4, -4], [12, -4], [12, 5], [4, 5]]]
  cell_size_m: 1.0
camera:
  width_px: 640
  height_px: 480
  K: [[457.0, 0.0, 319.5], [0.0, 457.0, 239.5], [0.0, 0.0, 1.0]]
  frame_rate_hz: 2
mount: {type: fixed, roll_deg: 0, pitch_deg: -90, yaw_deg: 0}
detector: illustrative
thresholds: [0.5, 0.9]
"""
