"""Terrain-following plans, and the check that terrain plus a clearance stays below a path.

The rule is QGroundControl's survey "vehicle follows terrain" (TransectStyleComplexItem:
``_buildFlightPathCoordInfoFromPathHeightInfoForCalcAboveTerrain``, ``_adjustForMaxRates``,
``_adjustForTolerance``), with the tolerance measured on the path:

1. every leg is sampled every half terrain cell; the profile there is the terrain height
   plus the waypoints' altitude above ground (ENU z);
2. AMSL plans (MAV_FRAME_GLOBAL) respect the climb and descent rates at the leg's speed
   (time = horizontal distance / speed, as QGC): where the profile would climb faster than
   ``max_climb_mps`` the points before it are raised (the climb starts earlier), where it
   would descend faster than ``max_descent_mps`` the points after it are raised (the
   descent ends later). The path only rises; this is the lowest profile meeting both
   limits, in closed form (QGC repeats passes until nothing changes). Terrain-frame plans
   (MAV_FRAME_GLOBAL_TERRAIN_ALT) are not raised: the autopilot holds its height above
   its own terrain data and its own rates (ArduCopter slows down along the leg);
3. of the samples, points are kept so that the straight path between kept points stays
   within ``tolerance_m`` of the profile at every sample (Douglas-Peucker on height against
   distance along the leg). QGC keeps a point when its height differs by more than the
   tolerance from the last kept point's, which bounds the steps but not the path between
   them. The pattern's own waypoints are always kept; a straight path between kept points
   meets the rate limits because every sample step does. Terrain-frame plans keep their
   points within TERRAIN_ALT_PROFILE_M instead: their file carries only the pattern's
   waypoints and the autopilot holds the height above terrain all along the leg, so the
   kept points are only the prediction's path, and at the tolerance it would fly up to
   2 m off the height the vehicle holds (at 10 m, 20 % off every cell's pixel size).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from pdcov.core.mission import AltitudeFrame
from pdcov.core.terrain import TerrainSurface
from pdcov.planning.plan import Plan, Waypoint
from pdcov.planning.plan_items import takeoff_alt_m

TERRAIN_ALT_PROFILE_M = 0.1
"""How far (m) a terrain-frame plan's predicted path may stray from the height above terrain
the autopilot holds (at most ``tolerance_m``)."""


@dataclass(frozen=True, slots=True)
class TerrainFollowing:
    """How plans meet the terrain: the frame they are written in (RELATIVE: they do not
    follow it, a constant altitude above home), the tolerance (m) on the height above
    terrain, the climb and descent rates (m/s; 0: no limit; AMSL plans keep to them,
    terrain-frame plans are warned about: ``steep_legs``), and the clearance (m) the terrain
    must keep below every path (``clearance_intrusions``).

    Defaults: QGC's rule, with ArduCopter's auto-mode rates (WPNAV_SPEED_UP 2.5 m/s,
    WPNAV_SPEED_DN 1.5 m/s) rather than QGC's "no limit", and a 2 m tolerance rather than
    QGC's 10 m, which at the paper's 8-12 m heights would let the path touch the ground."""

    frame: AltitudeFrame = AltitudeFrame.AMSL
    tolerance_m: float = 2.0
    max_climb_mps: float = 2.5
    max_descent_mps: float = 1.5
    clearance_m: float = 10.0

    def __post_init__(self) -> None:
        if not (self.tolerance_m > 0 and math.isfinite(self.tolerance_m)):
            raise ValueError(f"terrain_tolerance_m must be > 0 m, got {self.tolerance_m}")
        for name, v in (("terrain_max_climb_mps", self.max_climb_mps),
                        ("terrain_max_descent_mps", self.max_descent_mps),
                        ("terrain_clearance_m", self.clearance_m)):
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be >= 0 (0: none), got {v}")


def follow_terrain(plan: Plan, terrain: TerrainSurface, following: TerrainFollowing) -> Plan:
    """``plan`` at its waypoints' altitudes above ``terrain`` (module doc), in
    ``following.frame``. A RELATIVE frame, or a plan already in another frame, is returned
    as it is."""
    if following.frame is AltitudeFrame.RELATIVE or \
            plan.altitude_frame is not AltitudeFrame.RELATIVE:
        return plan
    wps = plan.waypoints
    xy, alt, speed, wp_at = _samples(plan, terrain.geometry.cell_size_m / 2)
    z = terrain.height_m(xy[:, 0], xy[:, 1]) + alt
    ds = np.concatenate([[0.0], np.linalg.norm(np.diff(xy, axis=0), axis=1)])
    s = np.cumsum(ds)
    if following.frame is AltitudeFrame.AMSL:
        t = np.cumsum(ds / speed)
        c, d = following.max_climb_mps, following.max_descent_mps
        if c > 0:  # z[k] >= z[j] - c (t_j - t_k) for every later j
            z = np.maximum(z, np.maximum.accumulate((z - c * t)[::-1])[::-1] + c * t)
        if d > 0:  # z[k] >= z[j] - d (t_k - t_j) for every earlier j
            z = np.maximum(z, np.maximum.accumulate(z + d * t) - d * t)
    tol = following.tolerance_m if following.frame is AltitudeFrame.AMSL else \
        min(following.tolerance_m, TERRAIN_ALT_PROFILE_M)
    keep = np.zeros(len(z), dtype=bool)
    keep[wp_at] = True
    for a, b in zip(wp_at[:-1], wp_at[1:], strict=True):
        _keep_within(s, z, int(a), int(b), tol, keep)
    # The waypoint at or after each sample: its own, or the one its leg flies towards.
    leg_of = np.searchsorted(wp_at, np.arange(len(z)))
    out = []
    for k in np.flatnonzero(keep):
        i = int(leg_of[k])
        if wp_at[i] == k:
            out.append(replace(wps[i], z_enu_m=float(z[k])))
        else:
            out.append(Waypoint(float(xy[k, 0]), float(xy[k, 1]), float(alt[k]),
                                wps[i].speed_mps, z_enu_m=float(z[k]), terrain_added=True,
                                gimbal=wps[i].gimbal,  # in force from the leg's start
                                zoom_hfov_deg=wps[i].zoom_hfov_deg))
    return replace(plan, waypoints=tuple(out), altitude_frame=following.frame,
                   description=f"{plan.description}; follows terrain ({following.frame})")


def _samples(plan: Plan, step_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                  np.ndarray]:
    """Points along the plan's legs at most ``step_m`` apart: ENU xy (K, 2), altitude above
    ground (K,) and speed (K,) towards each, and the sample index of each waypoint (N,)
    (whose point is the waypoint's own, exactly)."""
    wps = plan.waypoints
    xy0 = plan.xy_enu_m
    xy, alt, speed, wp_at = [xy0[:1]], [np.array([wps[0].alt_agl_m])], \
        [np.array([wps[0].speed_mps])], [0]
    for i in range(len(wps) - 1):
        m = max(1, math.ceil(float(np.linalg.norm(xy0[i + 1] - xy0[i])) / step_m))
        f = np.arange(1, m + 1) / m
        pts = xy0[i] + f[:, None] * (xy0[i + 1] - xy0[i])
        pts[-1] = xy0[i + 1]
        xy.append(pts)
        alt.append(wps[i].alt_agl_m + f * (wps[i + 1].alt_agl_m - wps[i].alt_agl_m))
        alt[-1][-1] = wps[i + 1].alt_agl_m
        speed.append(np.full(m, wps[i + 1].speed_mps))
        wp_at.append(wp_at[-1] + m)
    return (np.concatenate(xy), np.concatenate(alt), np.concatenate(speed),
            np.array(wp_at))


def _keep_within(s: np.ndarray, z: np.ndarray, a: int, b: int, tol: float,
                 keep: np.ndarray) -> None:
    """Mark in ``keep`` the samples of (a, b) that keep the straight path between marked
    points within ``tol`` of ``z`` at every sample (Douglas-Peucker, heights against
    distance ``s``)."""
    stack = [(a, b)]
    while stack:
        i, j = stack.pop()
        if j - i < 2 or s[j] <= s[i]:
            continue
        k = np.arange(i + 1, j)
        chord = z[i] + (z[j] - z[i]) * (s[k] - s[i]) / (s[j] - s[i])
        dev = np.abs(z[k] - chord)
        worst = int(np.argmax(dev))
        if dev[worst] > tol:
            m = i + 1 + worst
            keep[m] = True
            stack += [(i, m), (m, j)]


@dataclass(frozen=True, slots=True)
class Intrusion:
    """Where the terrain plus the clearance rises into a path: the stretch ("take-off to
    waypoint 1", "leg from waypoint 3 to 4", "return to launch"; waypoints numbered as the
    mission file's, from 1), the distance along it (m), the point (ENU m), the terrain's
    (the top of what stands on it: trees, roofs) and the path's heights there (m, ENU z)
    and the clearance (m). The worst point of each stretch."""

    stretch: str
    along_m: float
    x_enu_m: float
    y_enu_m: float
    terrain_z_enu_m: float
    path_z_enu_m: float
    clearance_m: float

    def message(self) -> str:
        above_m = self.path_z_enu_m - self.terrain_z_enu_m
        side = f"{above_m:.1f} m above" if above_m >= 0 else f"{-above_m:.1f} m below"
        return (f"{self.stretch}, {self.along_m:.0f} m along at ENU ({self.x_enu_m:.1f}, "
                f"{self.y_enu_m:.1f}) m: the path is {side} the terrain, within the "
                f"clearance {self.clearance_m:g} m (terrain {self.terrain_z_enu_m:.1f} m, "
                f"path {self.path_z_enu_m:.1f} m above the origin's ground)")


def clearance_intrusions(plan: Plan, terrain: TerrainSurface,
                         clearance_m: float) -> list[Intrusion]:
    """The stretches of the flight where terrain (the top of what stands on it, with a
    cover: ``TerrainSurface.surface_z_m``) + ``clearance_m`` rises above the path:
    the climb from the take-off (straight above home, at ``takeoff_alt_m``) to the first
    waypoint, every leg (straight between waypoints, as flown), and the return to launch
    at the last waypoint's height (ArduCopter climbs to RTL_ALT first when that is higher,
    so this is the lowest return). Sampled every half terrain cell."""
    xyz = plan.xyz_enu_m
    stretches = [("take-off to waypoint 1", np.array([0.0, 0.0, takeoff_alt_m(plan)]), xyz[0])]
    stretches += [(name, xyz[i], xyz[i + 1]) for i, name in enumerate(_leg_names(plan))]
    stretches.append(("return to launch", xyz[-1], np.array([0.0, 0.0, xyz[-1, 2]])))
    step = terrain.geometry.cell_size_m / 2
    worst: dict[str, Intrusion] = {}
    start_of: dict[str, np.ndarray] = {}
    for name, p, q in stretches:
        start_of.setdefault(name, p)
        length = float(np.linalg.norm(q[:2] - p[:2]))
        f = np.linspace(0.0, 1.0, max(2, math.ceil(length / step) + 1))
        pts = p + f[:, None] * (q - p)
        ground = terrain.surface_z_m(pts[:, 0], pts[:, 1])
        margin = pts[:, 2] - ground - clearance_m
        k = int(np.argmin(margin))
        if margin[k] >= 0:
            continue
        found = Intrusion(name, float(np.linalg.norm(pts[k, :2] - start_of[name][:2])),
                          float(pts[k, 0]), float(pts[k, 1]), float(ground[k]),
                          float(pts[k, 2]), clearance_m)
        old = worst.get(name)
        if old is None or (found.path_z_enu_m - found.terrain_z_enu_m
                           < old.path_z_enu_m - old.terrain_z_enu_m):
            worst[name] = found
    return list(worst.values())


def _leg_names(plan: Plan) -> list[str]:
    """Per piece of path between consecutive waypoints, the leg of the mission it lies on,
    "leg from waypoint A to B", numbered as the mission's waypoints from 1."""
    number = np.cumsum(plan.written())  # mission waypoint number of the last one so far
    return [f"leg from waypoint {number[i]} to {number[i] + 1}"
            for i in range(len(plan.waypoints) - 1)]


def steep_legs(plan: Plan, following: TerrainFollowing) -> list[str]:
    """For a MAV_FRAME_GLOBAL_TERRAIN_ALT plan, one line per leg where holding the height
    above terrain at the planned speed needs more than the climb or descent rate (the
    autopilot then slows down along the leg, or falls below its height on a climb), at the
    steepest point; none for other plans (an AMSL plan meets the rates by construction)."""
    if plan.altitude_frame is not AltitudeFrame.TERRAIN_ALT:
        return []
    xyz = plan.xyz_enu_m
    dxy = np.linalg.norm(np.diff(xyz[:, :2], axis=0), axis=1)
    speed = np.array([w.speed_mps for w in plan.waypoints[1:]])
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = np.where(dxy > 0, np.diff(xyz[:, 2]) * speed / dxy, 0.0)
    c, d = following.max_climb_mps, following.max_descent_mps
    excess = np.maximum(rate - c if c > 0 else 0.0, -rate - d if d > 0 else 0.0)
    worst: dict[str, int] = {}
    for i, name in enumerate(_leg_names(plan)):
        if excess[i] > 0 and (name not in worst or excess[i] > excess[worst[name]]):
            worst[name] = i
    lines = []
    for name, i in worst.items():
        up = rate[i] > 0
        lines.append(f"{name}, at ENU ({xyz[i, 0]:.1f}, {xyz[i, 1]:.1f}) m: holding the "
                     f"height above terrain at {speed[i]:g} m/s needs "
                     f"{abs(rate[i]):.1f} m/s of {'climb' if up else 'descent'}, more than "
                     f"terrain_max_{'climb' if up else 'descent'}_mps "
                     f"{c if up else d:g}: the autopilot slows down there"
                     f"{' or falls below its height' if up else ''}")
    return lines
