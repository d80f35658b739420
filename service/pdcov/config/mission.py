"""A parsed mission config: ``Mission`` and its cameras (``MissionCamera``), the values the
commands, the daemon and the ground station read."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pdcov.config.terrain import DEFAULT_TERRAIN_MARGIN_M
from pdcov.core import dem as dem_rules
from pdcov.core.camera import CameraModel
from pdcov.core.dem import Dem
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.free_cells import FreeCells
from pdcov.core.geodesy import Origin
from pdcov.core.geolocate import Geolocation
from pdcov.core.grid import CoverageGrid
from pdcov.core.ground_cover import GroundCover
from pdcov.core.looks import LooksConfig
from pdcov.core.mount import GimbalMount
from pdcov.core.pose import FixedMount
from pdcov.core.terrain import TerrainSurface
from pdcov.core.zoom import Zoom
from pdcov.errors import ConfigError, where

DEFAULT_THRESHOLDS = (0.5, 0.7, 0.8)
MAX_THRESHOLDS = 64
"""Most thresholds a mission may list: the bus's bound too (a watcher refuses a status with
more; bus/status.py)."""


@dataclass(frozen=True, slots=True)
class MissionCamera:
    """One camera of the mission: its name (outputs per camera), calibration, frame rate
    (Hz), mount (or gimbal device), detector model, zoom (its zoom lens and reports,
    core/zoom.py; None: a fixed lens, the configured K for every frame) and exposure time
    (s, motion blur is computed over; None: not given, no motion blur effect)."""

    name: str
    camera: CameraModel
    frame_rate_hz: float
    mount: FixedMount | GimbalMount
    detector: DetectorModel
    zoom: Zoom | None = None
    exposure_s: float | None = None


@dataclass(frozen=True, slots=True)
class Mission:
    """A parsed mission config.

    ground_alt_msl_m: ground altitude at the origin (m MSL); None = the autopilot's home
    altitude, resolved from the log or link; ground_alt_how: where a known one came from
    ('configured', or 'the DEM at the origin'). terrain: the ground under the grid's cell
    corners (ENU), dem: the DEM it came from (heights MSL at any lat/lon near the domain),
    both None without a ``terrain`` section; terrain_check_margin_m: terrain.check_margin_m.
    warnings: what loading found that the commands must show (a DEM that disagrees with
    origin.ground_alt_msl_m). max_range_m / min_revisit_s / looks: CoverageGrid
    options (None = its defaults). min_height_m: frames with the camera lower than this above
    the ground (on the ground, taking off) are not evaluated. frame_source: 'rate' or
    'capture' ('rate' when log.frame_source is not set); frame_source_set: whether the
    config sets it (``chosen_frame_source``). max_gap_s: telemetry gap that skips frames.
    system_id: the autopilot to follow (None = from its HEARTBEAT). estimator_status: skip
    frames whose position the autopilot's estimator calls bad (telemetry/estimator.py);
    false ignores it. terrain: ground heights under the grid (ENU; None: the flat ground
    z = 0), carrying what stands on the ground with terrain.surface (``cover``).
    domain: the searched domain, whose free cells every grid, hash, checkpoint, payload and
    prediction's score has: with terrain.surface the cells under solid cover are obstacles
    of it too unless terrain.search_under_roofs. configured_domain: the domain as the
    config gives it when ``domain`` differs (None: ``domain``); planners fly over
    ``flight_domain``. geolocation, gate_sigmas: the ``detections`` section (how
    boxes are located and grouped). prior_people_per_km2: ``search.prior_people_per_km2``.
    cameras: every camera, at least one, in config order (the single ``camera``, ``mount``
    and ``detector`` sections are one camera named 'camera'; a ``cameras`` list its
    entries); their looks go into the same cells (``several_cameras``).
    """

    vehicle_id: str
    origin_lat_deg: float
    origin_lon_deg: float
    ground_alt_msl_m: float | None
    domain: Domain
    cell_size_m: float
    cameras: tuple[MissionCamera, ...]
    thresholds: tuple[float, ...] = DEFAULT_THRESHOLDS
    max_range_m: float | None = None
    min_revisit_s: float | None = None
    min_height_m: float = 1.0
    looks: LooksConfig = LooksConfig()
    frame_source: str = "rate"
    frame_source_set: bool = False
    max_gap_s: float = 1.0
    system_id: int | None = None
    estimator_status: bool = True
    ground_alt_how: str = "configured"
    terrain: TerrainSurface | None = field(default=None, compare=False, repr=False)
    dem: Dem | None = field(default=None, compare=False, repr=False)
    configured_domain: Domain | None = field(default=None, repr=False)
    terrain_check_margin_m: float = DEFAULT_TERRAIN_MARGIN_M
    terrain_max_home_offset_m: float = dem_rules.DEFAULT_MAX_HOME_OFFSET_M
    geolocation: Geolocation = Geolocation()
    gate_sigmas: float = 3.0
    prior_people_per_km2: float = 1.0
    warnings: tuple[str, ...] = ()
    source: str | None = None
    raw: Mapping[str, Any] = field(default_factory=dict, repr=False)

    @property
    def cover(self) -> GroundCover | None:
        """What stands on the ground under the grid (terrain.surface; None without one)."""
        return None if self.terrain is None else self.terrain.cover

    @property
    def flight_domain(self) -> Domain:
        """Where the planners fly (ENU m; lines, transits, vantage points and their
        clearance, datums): the domain as configured, its boundary and the config's own
        obstacles. ``domain``, the searched one, may also have the cells under roofs as
        obstacles (terrain.surface): a drone flies over them at altitude, the clearance
        above their tops being checked (planning/terrain_follow.py
        ``clearance_intrusions``). Without them, ``domain`` itself (the same object)."""
        return self.domain if self.configured_domain is None else self.configured_domain

    @property
    def chosen_frame_source(self) -> str | None:
        """log.frame_source as the config sets it; when it does not, the daemon's
        service.frame_source in the same file if that is 'rate' or 'capture' (its recording
        then evaluates as it flew); else None: ``pdcov evaluate`` then uses the detector
        frames a daemon recorded in the log, if any (recorded_frames.frame_source_for),
        else 'rate'."""
        if self.frame_source_set:
            return self.frame_source
        service = self.raw.get("service")
        daemon = service.get("frame_source") if isinstance(service, Mapping) else None
        return daemon if daemon in ("rate", "capture") else None

    def __post_init__(self) -> None:
        if not self.cameras:
            raise ConfigError(f"{where(self.source, 'cameras')}: no camera (give camera, "
                              "mount and detector, or a cameras list)")

    @property
    def first_camera(self) -> MissionCamera:
        """The camera of the rules that follow one camera whatever the list (the first in
        config order; docs/mission-config.md "More than one camera"): the detector boxes'
        geolocation, the status's pose and footprint, the detector's frame times, the
        footprint figure, planning and refly, mount-check and the simulator."""
        return self.cameras[0]

    def only_camera(self, at: str | Path, why: str) -> MissionCamera:
        """The mission's one camera, for a rule that cannot tell cameras apart; with
        ``several_cameras``, ConfigError naming ``at`` (a key of this config, a command-line
        option '--...', or a file) and saying ``why``."""
        if not self.several_cameras:
            return self.cameras[0]
        named = (str(at) if isinstance(at, Path) or at.startswith("--")
                 else where(self.source, at))
        raise ConfigError(f"{named}: {why}")

    def cameras_frame_source(self, frame_source: str | None, key: str) -> str | None:
        """The frame source to frame the mission's cameras by: ``frame_source`` itself with
        one camera; with several 'rate' (also when None: not set), and ConfigError
        naming ``key`` (a config key, or a command-line option '--...') for any other:
        capture events and detector frames do not say which camera took them."""
        if frame_source in (None, "rate"):
            return "rate" if self.several_cameras else frame_source
        self.only_camera(key, f"{frame_source} with a cameras list: capture events and "
                         "detector frames do not say which camera took them; several "
                         "cameras are framed at their camera.frame_rate_hz (frame_source "
                         "rate)")
        return frame_source

    def origin(self, ground_alt_msl_m: float | None = None) -> Origin:
        """The ENU origin; the ground altitude given here overrides the configured one."""
        alt = ground_alt_msl_m if ground_alt_msl_m is not None else self.ground_alt_msl_m
        return Origin(self.origin_lat_deg, self.origin_lon_deg, alt or 0.0)

    def new_grid(self, cam: MissionCamera) -> CoverageGrid:
        """An empty coverage grid over the domain's free cells, for ``cam`` (one of
        ``cameras``)."""
        return self._grid(cam, self.looks)

    @property
    def several_cameras(self) -> bool:
        """More than one camera: the one rule for what a second camera changes. The
        mission's grid is then its cameras' grids combined (``combine_cameras`` into
        ``new_mission_grid``), each camera's grid an output of its own (cameras/<name>/,
        the checkpoint's, ``frames.by_camera``), frames at the cameras' rates only
        (``cameras_frame_source``), zoom reports given to the camera that follows their
        component, and every camera in the checkpoint's hash. With one camera the
        mission's grid is that camera's: combining one grid gives its P_D, P_FA, counts,
        limiting and clocks bit for bit, but as an independent-looks grid, without the
        correlated or viewpoint looks state its grid.npz and checkpoint keep
        (tests/unit/test_cameras.py)."""
        return len(self.cameras) > 1

    def new_mission_grid(self) -> CoverageGrid:
        """An empty grid of the mission's looks: its one camera's (``new_grid``), or with
        ``several_cameras`` one for their looks together (``combine_cameras`` writes it;
        independent looks: it holds the derived log-miss; the first camera's camera and
        detector for its range and figures)."""
        if not self.several_cameras:
            return self.new_grid(self.cameras[0])
        return self._grid(self.first_camera, None)

    def _grid(self, cam: MissionCamera, looks: LooksConfig | None) -> CoverageGrid:
        """An empty grid over the domain's free cells (found tile by tile as frames touch
        them) with ``cam``'s camera, detector model and exposure."""
        g = self.domain.grid_geometry(self.cell_size_m)
        return CoverageGrid(g, FreeCells(g, free_space=self.domain.free_space), cam.camera,
                            cam.detector, max_range_m=self.max_range_m,
                            min_revisit_s=self.min_revisit_s, terrain=self.terrain,
                            exposure_s=cam.exposure_s, looks=looks)

    def camera_grids(self, mission_grid: CoverageGrid,
                     resumed: Mapping[str, CoverageGrid] | None = None
                     ) -> dict[str, CoverageGrid]:
        """Each camera's grid by name, beside ``mission_grid`` (``new_mission_grid``, or
        resumed): with one camera that grid itself; with ``several_cameras`` the
        ``resumed`` one of that name, else a new one (``new_grid``)."""
        if not self.several_cameras:
            return {self.cameras[0].name: mission_grid}
        resumed = resumed or {}
        return {c.name: resumed.get(c.name) or self.new_grid(c) for c in self.cameras}
