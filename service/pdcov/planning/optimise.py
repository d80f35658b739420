"""Predict a plan's coverage, and choose plans by sweeping pattern parameters (the paper's
future work): every combination is built, flown kinematically at the camera frame rate
through the coverage grid, and scored by the proportion of free cells whose predicted P_D
reaches the target; the plans on the Pareto front of that proportion against flight time
are reported.
"""

from __future__ import annotations

import itertools
import math
import multiprocessing
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal, get_args

import numpy as np
from shapely.geometry import MultiPolygon, Polygon

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.footprint import footprint_polygon
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_camera import default_max_range_m
from pdcov.core.looks import LooksConfig
from pdcov.core.mount import GimbalMount
from pdcov.core.pose import CameraPose, FixedMount
from pdcov.core.rotations import Rz
from pdcov.core.terrain import TerrainSurface
from pdcov.core.zoom import FovLens, Zoom
from pdcov.errors import ConfigError
from pdcov.planning import patterns
from pdcov.planning.plan import Plan
from pdcov.planning.progress import progress as show_progress
from pdcov.planning.terrain_follow import TerrainFollowing, follow_terrain
from pdcov.planning.trajectory import Flight, Kinematics, camera_poses, flight_pointing, fly

PatternName = Literal["lawnmower", "spiral", "expanding-square", "sector", "sector-2",
                      "vantage"]
"""A coverage pattern of planning/patterns.py, or the vantage points of planning/vantage.py
(planned for a target P_D, not swept: ``vantage_score``), as `pdcov plan --pattern` names
it."""
PATTERNS: tuple[PatternName, ...] = get_args(PatternName)


@dataclass(frozen=True, slots=True)
class Scenario:
    """What a prediction needs from the mission: free_space, where plans fly (ENU m: their
    lines, transits, datums, vantage points and clearances; ``Mission.flight_domain``'s,
    over roofs too), its grid (geometry) and mask, the free cells a plan is scored on (bool,
    the grid's shape: the searched domain's, without roofs), camera, detector,
    mount, frame rate (Hz), the grid's range limit (m; None = the grid's default) and the
    vehicle's kinematic limits; gimbal_pitch_rad is the pitch a gimbal is assumed to hold;
    terrain: the ground under the grid (ENU; None: the plane z = 0) and how plans follow it;
    exposure_s: the camera's exposure time (s), for motion blur (None: no blur effect);
    looks: how a person's looks combine in the predicted grids (coverage.looks);
    zoom: the camera's zoom lens (core/zoom.py; None: a fixed lens), for plans that zoom."""

    free_space: Polygon | MultiPolygon
    geometry: GridGeometry
    mask: np.ndarray
    camera: CameraModel
    detector: DetectorModel
    mount: FixedMount | GimbalMount
    frame_rate_hz: float
    max_range_m: float | None = None
    min_revisit_s: float | None = None
    kinematics: Kinematics = Kinematics()
    gimbal_pitch_rad: float = -math.pi / 2
    terrain: TerrainSurface | None = None
    following: TerrainFollowing = TerrainFollowing()
    exposure_s: float | None = None
    looks: LooksConfig = LooksConfig()
    zoom: Zoom | None = None

    def camera_at(self, zoom_hfov_deg: float | None) -> CameraModel:
        """The camera zoomed to a horizontal field of view (deg; None: the configured
        camera), through the mission's zoom lens (camera.zoom fov_status); ConfigError
        without one or outside its calibrated range."""
        if zoom_hfov_deg is None:
            return self.camera
        lens = None if self.zoom is None else self.zoom.lens
        if not isinstance(lens, FovLens):
            raise ConfigError(f"a zoom of {zoom_hfov_deg:g} deg needs camera.zoom fov_status "
                              "(the lens the field of view maps to a focal length through)")
        why = lens.refusal(math.radians(zoom_hfov_deg))
        if why:
            raise ConfigError(f"zoom {zoom_hfov_deg:g} deg: {why}")
        return lens.camera(math.radians(zoom_hfov_deg))

    def over_terrain(self, plan: Plan) -> Plan:
        """``plan`` following the scenario's terrain (``follow_terrain``); without terrain,
        ``plan``."""
        if self.terrain is None:
            return plan
        return follow_terrain(plan, self.terrain, self.following)

    def new_grid(self) -> CoverageGrid:
        return CoverageGrid(self.geometry, self.mask, self.camera, self.detector,
                            max_range_m=self.max_range_m, min_revisit_s=self.min_revisit_s,
                            terrain=self.terrain, exposure_s=self.exposure_s,
                            looks=self.looks)

    def swath_width_m(self, alt_agl_m: float, heading_rad: float = 0.0,
                      zoom_hfov_deg: float | None = None) -> float:
        """Ground strip seen across the track by a level vehicle at ``alt_agl_m`` flying
        ``heading_rad``, within the grid's range limit (metres), with the camera zoomed to
        ``zoom_hfov_deg`` (None: as configured)."""
        camera = self.camera_at(zoom_hfov_deg)
        level = Flight(np.zeros(1), np.array([[0.0, 0.0, alt_agl_m]]),
                       Rz(heading_rad)[None], np.zeros(1), 0.0, 0.0)
        (pose,) = camera_poses(level, self.mount, self.gimbal_pitch_rad)
        max_range_m = self.max_range_m or default_max_range_m(
            camera, self.detector, self.geometry.cell_size_m)
        fp = footprint_polygon(camera, pose, max_range_m)
        return patterns.swath_width_m(fp, heading_rad)


@dataclass(frozen=True, slots=True)
class PlanParams:
    """One candidate: pattern, altitude above ground (m), track spacing (m; None: from the
    swath and ``overlap``), speed (m/s), heading (rad; first leg or track direction), centre
    of a spiral or datum of the IAMSAR patterns (ENU m; None: automatic), sector radius (m;
    None: reach the whole free space), the camera's zoom for the whole plan as a horizontal
    field of view (deg; commanded at the first waypoint; None: no zoom command, the
    configured camera)."""

    pattern: PatternName
    alt_agl_m: float
    speed_mps: float
    heading_rad: float = 0.0
    spacing_m: float | None = None
    overlap: float = 0.2
    centre_enu_m: tuple[float, float] | None = None
    radius_m: float | None = None
    zoom_hfov_deg: float | None = None

    def __post_init__(self) -> None:
        if self.pattern not in PATTERNS:
            raise ConfigError(f"pattern: expected one of {PATTERNS}, got {self.pattern!r}")


# Which plan options each pattern uses: "spacing" (track spacing or side overlap),
# "heading", "centre" (spiral centre or IAMSAR datum), "radius" (sector).
PATTERN_OPTIONS: dict[PatternName, tuple[str, ...]] = {
    "lawnmower": ("spacing", "heading"),
    "spiral": ("spacing", "centre"),
    "expanding-square": ("spacing", "heading", "centre"),
    "sector": ("heading", "centre", "radius"),
    "sector-2": ("heading", "centre", "radius"),
    "vantage": ("vantage",)}


def refuse_options(pattern: PatternName, given: dict[str, str]) -> None:
    """Raise ConfigError when an option given (name -> how the user wrote it, e.g.
    ``{"spacing": "--spacing-m"}``) does not apply to ``pattern``: it would be ignored."""
    for name, flag in given.items():
        if name not in PATTERN_OPTIONS[pattern]:
            uses = ", ".join(PATTERN_OPTIONS[pattern])
            raise ConfigError(f"{flag} does not apply to the {pattern} pattern (it uses "
                              f"{uses}); leave it out")


@dataclass(frozen=True, slots=True)
class Prediction:
    """A plan flown through the coverage grid (the plan over the scenario's terrain)."""

    params: PlanParams
    plan: Plan
    flight: Flight
    grid: CoverageGrid


@dataclass(frozen=True, slots=True)
class Score:
    """A candidate's result: the spacing actually used, the proportion of free cells at or
    above the target P_D, flight time (s), flown path length (m), mean P_D, and the number
    of missions it takes (vantage plans: one per vehicle and sortie; flight_time_s is then
    the longest mission's, path_length_m the total)."""

    params: PlanParams
    spacing_m: float
    proportion: float
    flight_time_s: float
    path_length_m: float
    mean_pd: float
    missions: int = 1


def build_plan(scenario: Scenario, params: PlanParams) -> tuple[Plan, float]:
    """The plan for ``params`` and the track spacing it used (m)."""
    if params.pattern == "vantage":
        raise ConfigError("vantage points are planned for a target P_D "
                          "(planning/vantage_missions.py), not built from parameters")
    spacing = params.spacing_m
    if spacing is None:
        swath = scenario.swath_width_m(params.alt_agl_m, params.heading_rad,
                                       params.zoom_hfov_deg)
        spacing = patterns.track_spacing_m(swath, params.overlap)
    free, alt, v, h = (scenario.free_space, params.alt_agl_m, params.speed_mps,
                       params.heading_rad)
    c = None if params.centre_enu_m is None else np.asarray(params.centre_enu_m, dtype=float)
    if params.pattern == "lawnmower":
        plan = patterns.lawnmower(free, spacing, h, alt, v)
    elif params.pattern == "spiral":
        plan = patterns.spiral(free, spacing, alt, v, centre_enu_m=c)
    elif params.pattern == "expanding-square":
        plan = patterns.expanding_square(free, spacing, alt, v, datum_enu_m=c, heading_rad=h)
    else:  # sector-2: the IAMSAR second pattern, turned 30 deg, follows the first
        plan = patterns.sector_search(free, alt, v, datum_enu_m=c, heading_rad=h,
                                      radius_m=params.radius_m,
                                      second=params.pattern == "sector-2")
    if params.zoom_hfov_deg is not None:  # commanded on leaving home, held throughout
        scenario.camera_at(params.zoom_hfov_deg)  # refused before anything is flown
        first = replace(plan.waypoints[0], zoom_hfov_deg=params.zoom_hfov_deg)
        plan = replace(plan, waypoints=(first, *plan.waypoints[1:]))
    return plan, spacing


def predict(scenario: Scenario, plan: Plan, params: PlanParams | None = None,
            progress: bool = False) -> Prediction:
    """Fly ``plan``, over the scenario's terrain (``Scenario.over_terrain``), at the frame
    rate and accumulate every frame (``flight_poses``) in a fresh grid, each with the camera
    zoomed as the plan commands at its waypoint (``flight_cameras``)."""
    plan = scenario.over_terrain(plan)
    flight = fly(plan, scenario.frame_rate_hz, scenario.kinematics)
    cameras = flight_cameras(scenario, plan, flight)
    grid = scenario.new_grid()
    poses = flight_poses(scenario, plan, flight)
    for pose, camera in show_progress(zip(poses, cameras, strict=True), desc="frames",
                                      unit="frame", total=len(poses), enabled=progress):
        grid.update_with(pose, camera)
    return Prediction(params or PlanParams("lawnmower", plan.waypoints[0].alt_agl_m,
                                           plan.waypoints[0].speed_mps), plan, flight, grid)


def flight_cameras(scenario: Scenario, plan: Plan, flight: Flight) -> list[CameraModel]:
    """Per sample of ``flight`` (flown from ``plan``), the camera zoomed as the plan's
    mission commands there (``Plan.zooms_hfov_deg`` at the sample's waypoint; the zoom
    taken as instant on leaving the previous waypoint), one camera per zoom
    (``Scenario.camera_at``). ConfigError (one line) for a zoom outside the lens's
    calibrated range, naming the waypoint, and for a plan with a zoom item it cannot
    predict (``Plan.zoom_not_predicted``)."""
    if plan.zoom_not_predicted:
        raise ConfigError(f"{plan.zoom_not_predicted}: not predicted")
    if flight.waypoint_index is None:
        raise ValueError("the flight has no waypoint index (not flown by fly)")
    per_wp = plan.zooms_hfov_deg()
    by_zoom: dict[float | None, CameraModel] = {}
    for k, z in enumerate(per_wp):
        if z not in by_zoom:
            try:
                by_zoom[z] = scenario.camera_at(z)
            except ConfigError as exc:
                raise ConfigError(f"{plan.description or 'plan'}: waypoint {k}: {exc}"
                                  ) from None
    return [by_zoom[per_wp[int(k)]] for k in flight.waypoint_index]


def flight_poses(scenario: Scenario, plan: Plan, flight: Flight) -> list[CameraPose]:
    """The camera poses of ``plan`` flown as ``flight``: the scenario's mount, a gimbal
    slewing at the kinematics' rate to the pointings the plan's mission commands (before
    any: the scenario's pitch, the yaw following the heading)."""
    return camera_poses(flight, scenario.mount, scenario.gimbal_pitch_rad,
                        flight_pointing(plan, flight), scenario.kinematics.gimbal_rate_rad_s)


def score(scenario: Scenario, params: PlanParams, target_pd: float) -> Score:
    plan, spacing = build_plan(scenario, params)
    p = predict(scenario, plan, params)
    pd = p.grid.pd[scenario.mask]
    return Score(params, spacing, float((pd >= target_pd).mean()) if pd.size else 0.0,
                 p.flight.duration_s, p.flight.path_length_m,
                 float(pd.mean()) if pd.size else 0.0)


def candidates(patterns_: Sequence[PatternName], alts_m: Sequence[float],
               speeds_mps: Sequence[float], headings_rad: Sequence[float],
               spacings_m: Sequence[float] | None, overlaps: Sequence[float],
               zooms_hfov_deg: Sequence[float | None] = (None,)) -> list[PlanParams]:
    """Every combination; heading is dropped for the spiral (it has none), so no duplicates.
    zooms_hfov_deg: the camera zooms to try with each altitude (None: not zoomed): flying
    higher at a longer focal length keeps people in the detector's best size bin over a
    narrower strip."""
    out: dict[PlanParams, None] = {}
    spacing_opts: list[tuple[float | None, float]] = (
        [(s, 0.0) for s in spacings_m] if spacings_m else [(None, o) for o in overlaps])
    for pat, alt, v, h, (s, o), z in itertools.product(patterns_, alts_m, speeds_mps,
                                                       headings_rad, spacing_opts,
                                                       zooms_hfov_deg):
        out[PlanParams(pat, alt, v, 0.0 if pat == "spiral" else h, s, o,
                       zoom_hfov_deg=z)] = None
    return list(out)


def pareto_front(scores: Sequence[Score]) -> list[int]:
    """Indices of the scores no other score dominates (at least as high a proportion and at
    least as short a flight, better in one), by increasing flight time."""
    idx = sorted(range(len(scores)), key=lambda i: (scores[i].flight_time_s,
                                                    -scores[i].proportion))
    front: list[int] = []
    best = -math.inf
    for i in idx:
        if scores[i].proportion > best:
            front.append(i)
            best = scores[i].proportion
    return front


def best_index(scores: Sequence[Score], min_proportion: float) -> int:
    """The shortest flight reaching ``min_proportion``, else the highest proportion."""
    ok = [i for i, s in enumerate(scores) if s.proportion >= min_proportion]
    if ok:
        return min(ok, key=lambda i: (scores[i].flight_time_s, -scores[i].proportion))
    return max(range(len(scores)), key=lambda i: (scores[i].proportion,
                                                  -scores[i].flight_time_s))


_WORKER: dict[str, Any] = {}


def _init_worker(scenario: Scenario, target_pd: float) -> None:
    _WORKER["scenario"], _WORKER["target"] = scenario, target_pd


def _score_in_worker(params: PlanParams) -> Score | str:
    try:
        return score(_WORKER["scenario"], params, _WORKER["target"])
    except ConfigError as exc:  # e.g. a camera that sees no ground at this altitude
        return f"{params}: {exc}"


def sweep(scenario: Scenario, params: Sequence[PlanParams], target_pd: float,
          processes: int | None = None, progress: bool = False
          ) -> tuple[list[Score], list[str]]:
    """Score every candidate on ``processes`` cores (default: all); returns the scores in
    the order of ``params`` (failed candidates left out) and one message per failure."""
    n_proc = max(1, min(processes or os.cpu_count() or 1, len(params)))
    results: list[Score | str]
    if n_proc == 1:
        _init_worker(scenario, target_pd)
        results = [_score_in_worker(p) for p in show_progress(params, desc="plans", unit="plan",
                                                              enabled=progress)]
    else:
        ctx = multiprocessing.get_context("spawn" if os.name == "nt" else "fork")
        with ctx.Pool(n_proc, initializer=_init_worker,
                      initargs=(scenario, target_pd)) as pool:
            it: Iterator[Score | str] = pool.imap(_score_in_worker, params, chunksize=1)
            results = list(show_progress(it, total=len(params), desc="plans", unit="plan",
                                         enabled=progress))
    return ([r for r in results if isinstance(r, Score)],
            [r for r in results if isinstance(r, str)])


def with_spacing(params: PlanParams, spacing_m: float) -> PlanParams:
    """The same candidate with its spacing fixed (to rebuild exactly the scored plan)."""
    return replace(params, spacing_m=spacing_m)
