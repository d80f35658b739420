"""The benchmark scenarios S1-S4 of issue 7, at full size and at the tiny CI ("smoke") size.

Every domain is a square with its south-west corner at the ENU origin. Poses come from
pdcov's own planner and kinematic flight model (patterns + trajectory), so that the
benchmark flies what a user would plan.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from shapely.geometry import box

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.detector_sections import LooksModel
from pdcov.core.domain import Domain
from pdcov.core.grid import CoverageGrid
from pdcov.core.looks import LooksConfig
from pdcov.core.pose import CameraPose, FixedMount
from pdcov.planning.patterns import lawnmower, spiral
from pdcov.planning.trajectory import Flight, camera_poses, fly
from tests.support.valley import Valley, ValleyDem

MILD_PLUMB_BOB = (-0.05, 0.01, 0.0005, -0.0005, 0.0)
FISHEYE_COEFFS = (0.01, -0.005, 0.001, 0.0)
ORIGIN_LAT_DEG, ORIGIN_LON_DEG = 39.35, -76.33
LOOKS_CORRELATION = 0.3  # rho of every bin in the correlated-looks rows


@dataclass(frozen=True)
class Scenario:
    """One benchmark scenario.

    side_m: the square domain's side (m); cell_m: cell side (m); camera: its model;
    camera_spec: (width_px, height_px, hfov_deg, model, coeffs) as in CameraModel.from_fov;
    alt_m: flight height above ground; off_nadir_deg: the fixed mount's tilt forward from
    nadir; rate_hz: camera frames per second; pattern: lawnmower or spiral; spacing_m: track
    spacing; speed_mps: ground speed; duration_s: flight time kept (the start of the plan).
    """

    name: str
    title: str
    side_m: float
    cell_m: float
    camera_spec: tuple[int, int, float, str, tuple[float, ...]]
    alt_m: float
    off_nadir_deg: float
    rate_hz: float
    pattern: str
    spacing_m: float
    speed_mps: float
    duration_s: float
    relief: ValleyDem | None = None

    @property
    def camera(self) -> CameraModel:
        return CameraModel.from_fov(*self.camera_spec)

    @property
    def mount(self) -> FixedMount:
        return FixedMount(pitch_rad=math.radians(self.off_nadir_deg - 90.0))

    @property
    def domain(self) -> Domain:
        s = self.side_m
        return Domain.from_enu([[0, 0], [s, 0], [s, s], [0, s]])

    def new_grid(self, looks: LooksConfig | None = None) -> CoverageGrid:
        """An empty grid of the illustrative detector; with ``looks`` (correlated), the
        model with a correlation of 0.3 in every bin."""
        g = self.domain.grid_geometry(self.cell_m)
        detector = DetectorModel.illustrative()
        if looks is not None:
            detector = dataclasses.replace(
                detector, looks=LooksModel((LOOKS_CORRELATION,) * detector.n_bins))
        return CoverageGrid(g, self.domain.free_mask(g), self.camera, detector, looks=looks)

    def flight(self, rate_hz: float) -> Flight:
        """The vehicle's states at ``rate_hz`` while flying the plan (all of it)."""
        free = box(0.0, 0.0, self.side_m, self.side_m)
        if self.pattern == "lawnmower":
            plan = lawnmower(free, self.spacing_m, 0.0, self.alt_m, self.speed_mps)
        else:
            plan = spiral(free, self.spacing_m, self.alt_m, self.speed_mps)
        return fly(plan, rate_hz)

    def poses(self) -> list[CameraPose]:
        """Camera poses at the frame rate over the first ``duration_s`` of the plan."""
        poses = camera_poses(self.flight(self.rate_hz), self.mount)
        return [p for p in poses if p.t_s <= self.duration_s]

    def mission_doc(self, dem_file: str | None = None) -> dict[str, Any]:
        """The scenario as a mission config mapping (docs/mission-config.md); with a
        ``relief``, its origin and ``terrain.dem`` = ``dem_file``."""
        cam = self.camera
        s = self.side_m
        doc = {
            "vehicle_id": f"bench_{self.name.lower().replace(' ', '_')}",
            "origin": {"lat_deg": ORIGIN_LAT_DEG, "lon_deg": ORIGIN_LON_DEG,
                       "ground_alt_msl_m": 0.0},
            "domain": {"polygon_enu_m": [[0, 0], [s, 0], [s, s], [0, s]],
                       "cell_size_m": self.cell_m},
            "camera": {**cam.to_config(), "frame_rate_hz": self.rate_hz},
            "mount": {"type": "fixed", "roll_deg": 0, "pitch_deg": self.off_nadir_deg - 90.0,
                      "yaw_deg": 0},
            "detector": "illustrative",
            "thresholds": [0.5, 0.7, 0.8],
        }
        if self.relief is not None:
            r = self.relief
            doc["origin"] = {"lat_deg": r.origin_lat_deg, "lon_deg": r.origin_lon_deg,
                             "ground_alt_msl_m": r.floor_alt_msl_m}
            doc["terrain"] = {"dem": dem_file}
        return doc

    def describe(self) -> str:
        w, h, fov, model, _ = self.camera_spec
        cells = round(self.side_m / self.cell_m) ** 2
        ground = "" if self.relief is None else (
            f"valley DEM ({self.relief.spacing_m:g} m, UTM 32N), ")
        return (f"{ground}{self.side_m:g} m square at {self.cell_m:g} m ({cells:,} cells), {w}x{h} "
                f"{model} {fov:g} deg, {self.alt_m:g} m, {self.off_nadir_deg:g} deg off nadir, "
                f"{self.pattern} at {self.speed_mps:g} m/s, {self.rate_hz:g} frames/s, "
                f"{self.duration_s:g} s")


def scenarios(smoke: bool = False) -> dict[str, Scenario]:
    """S1-S4 (issue 7), S5 and S5 valley (issue 21); ``smoke``: the same shapes at a size CI
    runs in seconds."""
    s1_cam = (1920, 1080, 80.0, "plumb_bob", MILD_PLUMB_BOB)
    s4_cam = (1920, 1080, 150.0, "fisheye", FISHEYE_COEFFS)
    # The valley's camera: narrower than S1's, so that at 95 m above the floor a 1 m cell is
    # ~6 detector-input pixels and the terrain's nearness moves it through several bins.
    valley_cam = (1920, 1080, 60.0, "plumb_bob", MILD_PLUMB_BOB)
    if smoke:
        s1_cam = (480, 270, 80.0, "plumb_bob", MILD_PLUMB_BOB)
        s4_cam = (480, 270, 150.0, "fisheye", FISHEYE_COEFFS)
        found = [
            Scenario("S1", "survey", 120.0, 1.0, s1_cam, 15.0, 20.0, 30.0, "lawnmower", 20.0,
                     10.0, 3.0),
            Scenario("S2", "paper", 40.0, 1.0, (640, 480, 70.0, "plumb_bob", MILD_PLUMB_BOB),
                     10.0, 0.0, 5.0, "spiral", 8.0, 3.0, 8.0),
            Scenario("S3", "fine", 40.0, 0.25, (960, 540, 80.0, "plumb_bob", MILD_PLUMB_BOB),
                     8.0, 0.0, 30.0, "lawnmower", 8.0, 5.0, 2.0),
            Scenario("S4", "fisheye", 120.0, 1.0, s4_cam, 15.0, 20.0, 30.0, "lawnmower", 20.0,
                     10.0, 3.0),
            Scenario("S5", "terrain", 120.0, 1.0, s1_cam, 60.0, 20.0, 30.0, "lawnmower", 40.0,
                     10.0, 3.0, ValleyDem(Valley(120.0), 1.0, 120.0)),
            Scenario("S5 valley", "valley", 200.0, 1.0, valley_cam, 95.0, 28.0, 1.0,
                     "lawnmower", 100.0, 10.0, 600.0, ValleyDem(Valley(200.0), 1.0, 190.0)),
        ]
    else:
        found = [
            Scenario("S1", "survey", 1000.0, 1.0, s1_cam, 60.0, 20.0, 30.0, "lawnmower", 80.0,
                     10.0, 600.0),
            Scenario("S2", "paper", 40.0, 1.0, (640, 480, 70.0, "plumb_bob", MILD_PLUMB_BOB),
                     10.0, 0.0, 5.0, "spiral", 8.0, 3.0, 600.0),
            Scenario("S3", "fine", 200.0, 0.25,
                     (3840, 2160, 80.0, "plumb_bob", MILD_PLUMB_BOB), 30.0, 0.0, 30.0,
                     "lawnmower", 40.0, 5.0, 120.0),
            Scenario("S4", "fisheye", 1000.0, 1.0, s4_cam, 60.0, 20.0, 30.0, "lawnmower",
                     80.0, 10.0, 600.0),
            Scenario("S5", "terrain", 1000.0, 1.0, s1_cam, 95.0, 20.0, 30.0, "lawnmower", 80.0,
                     10.0, 600.0, ValleyDem(Valley(1000.0), 2.0, 200.0)),
            Scenario("S5 valley", "valley", 300.0, 1.0, valley_cam, 95.0, 28.0, 2.0,
                     "lawnmower", 120.0, 10.0, 600.0, ValleyDem(Valley(300.0), 1.0, 190.0)),
        ]
    return {s.name: s for s in found}


def spaced(poses: list[CameraPose], n: int, stride: int) -> list[CameraPose]:
    """``n`` poses ``stride`` frames apart from the middle of the flight (consecutive
    footprints overlap, so cells collect several looks)."""
    start = max(0, len(poses) // 2 - n * stride // 2)
    return poses[start:start + n * stride:stride]


def strided(poses: list[CameraPose], n: int) -> list[CameraPose]:
    """At most ``n`` poses spread evenly over the flight."""
    step = max(1, math.ceil(len(poses) / n))
    return poses[::step]
