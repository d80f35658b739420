"""A parsed mission config: ``Mission`` and its cameras (``MissionCamera``), the values the
commands, the daemon and the ground station read."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pdcov.config.terrain import DEFAULT_TERRAIN_MARGIN_M
from pdcov.core import dem as dem_rules
from pdcov.core.camera import CameraModel
from pdcov.core.dem import Dem
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.geodesy import Origin
from pdcov.core.geolocate import Geolocation
from pdcov.core.grid import CoverageGrid
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
    (Hz), mount (or gimbal device), detector model, zoom (None: a fixed lens) and exposure
    time (s; None: not given, no motion blur effect)."""

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
    z = 0). geolocation, gate_sigmas: the ``detections`` section (how boxes are located and
    grouped). prior_people_per_km2: ``search.prior_people_per_km2``. exposure_s:
    camera.exposure_s, the exposure time (s) motion blur is computed over (None: not
    given, no blur effect).
    zoom: the camera's zoom lens and reports (core/zoom.py; None: camera.zoom
    none, the configured K for every frame). extra_cameras: the ``cameras`` list's entries
    after the first (whose camera, mount, detector and zoom are the fields above, named
    camera_name); their looks go into the same cells (``all_cameras``).
    """

    vehicle_id: str
    origin_lat_deg: float
    origin_lon_deg: float
    ground_alt_msl_m: float | None
    domain: Domain
    cell_size_m: float
    camera: CameraModel
    frame_rate_hz: float
    mount: FixedMount | GimbalMount
    detector: DetectorModel
    exposure_s: float | None = None
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
    terrain_check_margin_m: float = DEFAULT_TERRAIN_MARGIN_M
    terrain_max_home_offset_m: float = dem_rules.DEFAULT_MAX_HOME_OFFSET_M
    geolocation: Geolocation = Geolocation()
    gate_sigmas: float = 3.0
    prior_people_per_km2: float = 1.0
    warnings: tuple[str, ...] = ()
    zoom: Zoom | None = None
    extra_cameras: tuple[MissionCamera, ...] = ()
    camera_name: str = "camera"
    source: str | None = None
    raw: Mapping[str, Any] = field(default_factory=dict, repr=False)

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

    def cameras_frame_source(self, frame_source: str | None, key: str) -> str | None:
        """The frame source to frame the mission's cameras by: ``frame_source`` itself with
        one camera; with a cameras list 'rate' (also when None: not set), and ConfigError
        naming ``key`` (a config key, or a command-line option '--...') for any other:
        capture events and detector frames do not say which camera took them."""
        if not self.extra_cameras:
            return frame_source
        if frame_source not in (None, "rate"):
            at = key if key.startswith("--") else where(self.source, key)
            raise ConfigError(f"{at}: {frame_source} with a cameras list: capture events and "
                              "detector frames do not say which camera took them; several "
                              "cameras are framed at their camera.frame_rate_hz (frame_source "
                              "rate)")
        return "rate"

    @property
    def all_cameras(self) -> tuple[MissionCamera, ...]:
        """Every camera of the mission, the primary (the fields above) first."""
        return (MissionCamera(self.camera_name, self.camera, self.frame_rate_hz, self.mount,
                              self.detector, self.zoom, self.exposure_s), *self.extra_cameras)

    def origin(self, ground_alt_msl_m: float | None = None) -> Origin:
        """The ENU origin; the ground altitude given here overrides the configured one."""
        alt = ground_alt_msl_m if ground_alt_msl_m is not None else self.ground_alt_msl_m
        return Origin(self.origin_lat_deg, self.origin_lon_deg, alt or 0.0)

    def new_grid(self, camera: MissionCamera | None = None) -> CoverageGrid:
        """An empty coverage grid over the domain's free cells, for ``camera`` (one of
        ``all_cameras``; None: the primary)."""
        g = self.domain.grid_geometry(self.cell_size_m)
        cam = self.all_cameras[0] if camera is None else camera
        return CoverageGrid(g, self.domain.free_mask(g), cam.camera, cam.detector,
                            max_range_m=self.max_range_m, min_revisit_s=self.min_revisit_s,
                            terrain=self.terrain, exposure_s=cam.exposure_s,
                            looks=self.looks)

    def new_combined_grid(self) -> CoverageGrid:
        """An empty grid for the looks of all the mission's cameras together
        (``grid.combine_cameras`` writes them; independent looks: it holds the derived
        log-miss)."""
        g = self.domain.grid_geometry(self.cell_size_m)
        return CoverageGrid(g, self.domain.free_mask(g), self.camera, self.detector,
                            max_range_m=self.max_range_m, min_revisit_s=self.min_revisit_s,
                            terrain=self.terrain, exposure_s=self.exposure_s)
