"""Mission config YAML (docs/mission-config.md): origin, domain, camera, mount, detector,
thresholds, the terrain (a DEM), and the coverage and log options. Every error names the
file, the key and what was expected.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Mapping
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.core import dem as dem_rules
from pdcov.core.camera import CameraModel
from pdcov.core.camera_config import CAMERA_CONFIG
from pdcov.core.dem import Dem, VerticalDatum, height_mismatch, terrain_surface
from pdcov.core.detections import CLASS_NAME_RULE, valid_class_name
from pdcov.core.detector import MODEL_SCHEMA, DetectorModel
from pdcov.core.domain import Domain, GridGeometry
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.geolocate import Geolocation
from pdcov.core.grid import CoverageGrid
from pdcov.core.looks import LooksConfig, LooksRule, ViewpointBins
from pdcov.core.mission import AltitudeFrame
from pdcov.core.mount import GIMBAL_MOUNT_CONFIG, GimbalMount
from pdcov.core.pose import FixedMount
from pdcov.core.terrain import TerrainSurface
from pdcov.core.zoom import FovLens, LensQuantity, TableLens, Zoom, ZoomLens
from pdcov.errors import CalibrationError, ConfigError, PdcovError, where
from pdcov.ids import SYSTEM_IDS, VEHICLE_ID_RULE, valid_system_id, valid_vehicle_id
from pdcov.schema import Section, Variants, check_keys
from pdcov.yaml_file import load_yaml

DEFAULT_THRESHOLDS = (0.5, 0.7, 0.8)
MAX_THRESHOLDS = 64
"""Most thresholds a mission may list: the bus's bound too (a watcher refuses a status with
more; bus/status.py)."""
_FLOAT_MAX = sys.float_info.max

# Sections of the onboard daemon (`pdcov serve`) and the ground station (`fleet`), declared
# by their own modules: see ``mission_schema``. Until a schema is passed for one, any
# mapping is accepted there.
RESERVED_SECTIONS = ("link", "bus", "service", "fleet")


# -- sections: each a dataclass whose fields are its keys (the schema reads them) ------------


MAX_FRAME_RATE_HZ = 1000.0  # camera.frame_rate_hz beyond: a typo (memory: serve --check)
DEFAULT_TERRAIN_MARGIN_M = 10.0
"""terrain.check_margin_m when the config does not set it (m): how far the DEM may disagree
with the home altitude and what the aircraft measures before it is said."""

@dataclass(frozen=True, slots=True)
class OriginSection:
    """``origin``: the ENU origin (degrees) and the ground altitude there (m MSL; None: the
    autopilot's home altitude)."""

    lat_deg: float
    lon_deg: float
    ground_alt_msl_m: float | None = None

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> OriginSection:
        ground = (None if doc.get("ground_alt_msl_m") is None
                  else _number(doc, "ground_alt_msl_m", src, "origin"))
        return cls(_number(doc, "lat_deg", src, "origin"), _number(doc, "lon_deg", src, "origin"),
                   ground)


@dataclass(frozen=True, slots=True)
class DomainSection:
    """``domain``: one of polygon_enu_m, polygon_geodetic_deg or geojson (a file), the
    obstacles in the same frame, and the grid's cell size (m). The polygons are read by
    ``Domain``; here they are kept as given."""

    polygon_enu_m: Any = None
    polygon_geodetic_deg: Any = None
    geojson: Any = None
    obstacles_enu_m: Any = None
    obstacles_geodetic_deg: Any = None
    cell_size_m: float = 1.0

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> DomainSection:
        cell = _number(doc, "cell_size_m", src, "domain", default=1.0, positive=True)
        return cls(**{**{k: v for k, v in doc.items() if k != "cell_size_m"},
                      "cell_size_m": cell})


@dataclass(frozen=True, slots=True)
class FixedMountSection:
    """``mount`` of ``type: fixed``: the camera's angles in the body frame (degrees) and its
    lever arm (m, forward-right-down); the gimbal's keys are ``GimbalMount``'s."""

    type: str = "fixed"
    roll_deg: float = 0.0
    pitch_deg: float = -90.0
    yaw_deg: float = 0.0
    lever_arm_frd_m: Any = (0.0, 0.0, 0.0)

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> FixedMountSection:
        default = _defaults(cls)
        angles = {k: _number(doc, k, src, "mount", default=default[k])
                  for k in ("roll_deg", "pitch_deg", "yaw_deg")}
        arm = doc.get("lever_arm_frd_m", [0.0, 0.0, 0.0])
        if (not isinstance(arm, list) or len(arm) != 3 or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) <= _FLOAT_MAX
                for v in arm)):
            raise ConfigError(f"{where(src, 'mount.lever_arm_frd_m')}: expected [forward, "
                              f"right, down] in metres, got {arm!r}")
        return cls("fixed", **angles,
                   lever_arm_frd_m=(float(arm[0]), float(arm[1]), float(arm[2])))

    def mount(self) -> FixedMount:
        return FixedMount(math.radians(self.roll_deg), math.radians(self.pitch_deg),
                          math.radians(self.yaw_deg), tuple(self.lever_arm_frd_m))


ZOOM_MODES = ("none", "fov_status", "table")
_TABLE_KEYS = ("zoom_level", "focal_length_mm")


@dataclass(frozen=True, slots=True)
class ZoomLensSection:
    """``camera.zoom_lens``: the zoom lens (core/zoom.py) for ``camera.zoom`` fov_status or
    table. min_hfov_deg: the narrowest horizontal field of view (fov_status; deg);
    fov_tolerance_deg: how far a report may lie outside the calibrated range and be taken as
    its end; max_zoom_rate_per_s: the fastest the lens zooms (|d ln f / dt|, 1/s);
    max_report_age_s: how long a report stays in force (s); component_id /
    camera_device_id: the camera whose reports count (None: the first heard); table_by:
    zoom_level (CAMERA_SETTINGS) or focal_length_mm (CAMERA_INFORMATION); table: entries of
    that key, K and distortion_coeffs (the size and distortion model are the camera's)."""

    min_hfov_deg: float | None = None
    fov_tolerance_deg: float = 1.0
    max_zoom_rate_per_s: float = 2.0
    max_report_age_s: float = 2.0
    component_id: int | None = None
    camera_device_id: int = 0
    table_by: str = "zoom_level"
    table: Any = None

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> ZoomLensSection:
        sec = "camera.zoom_lens"
        default = _defaults(cls)
        nums = {k: _number(doc, k, src, sec, default=default[k], positive=True)
                for k in ("max_zoom_rate_per_s", "max_report_age_s")}
        tol = _number(doc, "fov_tolerance_deg", src, sec, default=1.0)
        if tol < 0:
            raise ConfigError(f"{where(src, sec + '.fov_tolerance_deg')}: expected >= 0 deg, "
                              f"got {tol!r}")
        ids: dict[str, int | None] = {}
        for key, lo, dflt in (("component_id", 1, None), ("camera_device_id", 0, 0)):
            v = doc.get(key, dflt)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int)
                                  or not lo <= v <= 255):
                raise ConfigError(f"{where(src, sec + '.' + key)}: expected an integer "
                                  f"{lo}..255, got {v!r}")
            ids[key] = v
        table_by = doc.get("table_by", "zoom_level")
        if table_by not in _TABLE_KEYS:
            raise ConfigError(f"{where(src, sec + '.table_by')}: expected one of "
                              f"{', '.join(_TABLE_KEYS)}, got {table_by!r}")
        return cls(_opt_number(doc, "min_hfov_deg", src, sec), tol, **nums,
                   component_id=ids["component_id"],
                   camera_device_id=int(ids["camera_device_id"] or 0), table_by=table_by,
                   table=doc.get("table"))

    def zoom(self, mode: str, camera: CameraModel, src: str | None) -> Zoom:
        """The mission's Zoom for ``camera.zoom`` = mode (fov_status or table)."""
        sec = "camera.zoom_lens"
        lens: ZoomLens
        if mode == "fov_status":
            if self.min_hfov_deg is None:
                raise ConfigError(f"{where(src, sec + '.min_hfov_deg')}: missing: camera.zoom "
                                  "fov_status needs the narrowest field of view the lens "
                                  "reaches (deg)")
            try:
                lens = FovLens(camera, math.radians(self.min_hfov_deg),
                               math.radians(self.fov_tolerance_deg), self.max_zoom_rate_per_s)
            except CalibrationError as exc:
                raise CalibrationError(f"{src}: {exc}" if src else str(exc)) from None
        else:
            lens = self._table(camera, src)
        camera_id = (None if self.component_id is None
                     else (self.component_id, self.camera_device_id))
        return Zoom(lens, self.max_report_age_s, camera_id)

    def _table(self, camera: CameraModel, src: str | None) -> TableLens:
        sec = "camera.zoom_lens.table"
        rows = self.table
        if not isinstance(rows, list) or len(rows) < 2:
            raise ConfigError(f"{where(src, sec)}: camera.zoom table needs a list of at least "
                              f"two entries ({self.table_by}, K, distortion_coeffs), got "
                              f"{rows!r}")
        keys, cams = [], []
        for i, row in enumerate(rows):
            at = f"{sec}[{i}]"
            if not isinstance(row, dict):
                raise ConfigError(f"{where(src, at)}: expected a mapping, got {row!r}")
            extra = sorted(set(row) - {self.table_by, "K", "distortion_coeffs"})
            if extra:
                raise ConfigError(f"{where(src, at + '.' + str(extra[0]))}: unknown key; "
                                  f"expected {self.table_by}, K, distortion_coeffs")
            keys.append(_number(row, self.table_by, src, at))
            cams.append(CameraModel.from_config(
                {"width_px": camera.width_px, "height_px": camera.height_px,
                 "distortion_model": camera.distortion_model,
                 "distortion_coeffs": row.get("distortion_coeffs",
                                              camera.dist_coeffs.tolist()),
                 "K": row.get("K")}, src, at))
        return TableLens(LensQuantity(self.table_by), tuple(keys), tuple(cams),
                         self.max_zoom_rate_per_s, where(src, sec))


@dataclass(frozen=True, slots=True)
class CoverageSection:
    """``coverage``: CoverageGrid's max_range_m and min_revisit_s (None: its defaults),
    min_height_m: frames with the camera lower than this above the ground are not
    evaluated, looks: how one person's looks combine (core/looks.py) and viewpoint: the
    bins of ``looks: viewpoint``."""

    max_range_m: float | None = None
    min_revisit_s: float | None = None
    min_height_m: float = 1.0
    looks: LooksRule = LooksRule.INDEPENDENT
    viewpoint: ViewpointBins | None = None

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> CoverageSection:
        rule = doc.get("looks", str(LooksRule.INDEPENDENT))
        if rule not in tuple(str(r) for r in LooksRule):
            raise ConfigError(f"{where(src, 'coverage.looks')}: expected one of "
                              f"{', '.join(str(r) for r in LooksRule)}, got {rule!r}")
        view = doc.get("viewpoint")
        bins = None
        if view is not None:
            if rule != LooksRule.VIEWPOINT:
                raise ConfigError(f"{where(src, 'coverage.viewpoint')}: only used with "
                                  f"coverage.looks: viewpoint (it says {rule})")
            if not isinstance(view, dict):
                raise ConfigError(f"{where(src, 'coverage.viewpoint')}: expected a mapping "
                                  f"of azimuth_bins and elevation_bins, got {view!r}")
            try:
                bins = ViewpointBins(**view)
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"{where(src, 'coverage.viewpoint')}: {exc}") from None
        return cls(_opt_number(doc, "max_range_m", src, "coverage"),
                   _opt_number(doc, "min_revisit_s", src, "coverage"),
                   _number(doc, "min_height_m", src, "coverage", default=1.0),
                   LooksRule(rule), bins)

    def looks_config(self, detector: DetectorModel, src: str | None,
                     at: str = "coverage.looks") -> LooksConfig:
        """The grid's looks; ``correlated`` needs the detector model's looks section (``at``:
        the key the error names, e.g. cameras[1].detector)."""
        if self.looks is LooksRule.CORRELATED and detector.looks is None:
            rule = "correlated" if at == "coverage.looks" else "coverage.looks correlated"
            raise ConfigError(
                f"{where(src, at)}: {rule} needs the detector model's "
                f"looks section (looks.correlation per size bin, written by pdcov detector "
                f"fit from tracked sequences); {detector.source or 'the detector model'} has "
                "none. Use looks: independent or viewpoint, or fit the model on tracks")
        return LooksConfig(self.looks, self.viewpoint or ViewpointBins())


@dataclass(frozen=True, slots=True)
class TerrainSection:
    """``terrain``: the DEM file (GeoTIFF, COG or SRTM .hgt, any CRS; relative to the config's
    folder), the datum of its heights ('msl', or 'ellipsoid' with geoid_height_m, the geoid's
    height N above the ellipsoid at the site in m: H_msl = h_ellipsoid - N), the margin
    (m) beyond which an altitude measured or configured that disagrees with it is warned of,
    and the most (m) a configured home altitude may differ from it (else refused)."""

    dem: str
    vertical_datum: str = "msl"
    geoid_height_m: float | None = None
    check_margin_m: float = DEFAULT_TERRAIN_MARGIN_M
    max_home_offset_m: float = dem_rules.DEFAULT_MAX_HOME_OFFSET_M

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> TerrainSection:
        dem = doc.get("dem")
        if not isinstance(dem, str) or not dem:
            raise ConfigError(f"{where(src, 'terrain.dem')}: expected the path of a DEM file "
                              f"(GeoTIFF, Cloud-Optimized GeoTIFF, SRTM .hgt), got {dem!r}")
        datum = doc.get("vertical_datum", "msl")
        if datum not in tuple(VerticalDatum):
            raise ConfigError(f"{where(src, 'terrain.vertical_datum')}: expected 'msl' or "
                              f"'ellipsoid', got {datum!r}")
        geoid = (None if doc.get("geoid_height_m") is None
                 else _number(doc, "geoid_height_m", src, "terrain"))
        if datum == VerticalDatum.ELLIPSOID and geoid is None:
            raise ConfigError(f"{where(src, 'terrain.geoid_height_m')}: missing: with "
                              "vertical_datum: ellipsoid, give the geoid's height N above the "
                              "WGS84 ellipsoid at the site in metres (H_msl = h_ellipsoid - "
                              "N; EGM2008 gives it)")
        if datum == VerticalDatum.MSL and geoid is not None:
            raise ConfigError(f"{where(src, 'terrain.geoid_height_m')}: only used with "
                              "vertical_datum: ellipsoid (the DEM's heights are MSL)")
        return cls(dem, datum, geoid, *(_number(doc, k, src, "terrain", default=d, positive=True)
                   for k, d in (("check_margin_m", DEFAULT_TERRAIN_MARGIN_M),
                                ("max_home_offset_m", dem_rules.DEFAULT_MAX_HOME_OFFSET_M))))


@dataclass(frozen=True, slots=True)
class LogSection:
    """``log``: how frames are placed in a log (frame_source 'rate' or 'capture'), the
    telemetry gap that skips frames (s), the autopilot to follow (a MAVLink system id; None:
    from its HEARTBEAT) and whether the estimator's status can skip frames."""

    frame_source: str = "rate"
    max_gap_s: float = 1.0
    system_id: int | None = None
    estimator_status: bool = True

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> LogSection:
        frame_source = doc.get("frame_source", "rate")
        if frame_source not in ("rate", "capture"):
            raise ConfigError(f"{where(src, 'log.frame_source')}: expected 'rate' or "
                              f"'capture', got {frame_source!r}")
        system_id = doc.get("system_id")
        if system_id is not None and not valid_system_id(system_id):
            raise ConfigError(f"{where(src, 'log.system_id')}: expected a MAVLink system id "
                              f"{SYSTEM_IDS.start}..{SYSTEM_IDS.stop - 1}, got {system_id!r}")
        estimator_status = doc.get("estimator_status", True)
        if not isinstance(estimator_status, bool):
            raise ConfigError(f"{where(src, 'log.estimator_status')}: expected true or false, "
                              f"got {estimator_status!r}")
        return cls(frame_source,
                   _number(doc, "max_gap_s", src, "log", default=1.0, positive=True),
                   system_id, estimator_status)


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
        given = {**_defaults(cls), **doc}
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


@dataclass(frozen=True, slots=True)
class DetectionsSection:
    """``detections``: how the detector's boxes are geolocated and grouped
    (core/geolocate.py, detection/candidates.py): the classes located at their box's bottom
    centre (standing on the ground), the 1-sigma errors of the camera's attitude (deg), of
    its position (m) and of a box's pixel (px), and the grouping gate in combined sigmas."""

    standing_classes: Any = ("person", "pedestrian")
    roll_sigma_deg: float = 0.5
    pitch_sigma_deg: float = 0.5
    yaw_sigma_deg: float = 1.0
    horizontal_sigma_m: float = 1.0
    vertical_sigma_m: float = 1.0
    pixel_sigma_px: float = 2.0
    gate_sigmas: float = 3.0

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> DetectionsSection:
        default = _defaults(cls)
        classes = doc.get("standing_classes", list(default["standing_classes"]))
        if not isinstance(classes, list) or not all(valid_class_name(c) for c in classes):
            raise ConfigError(f"{where(src, 'detections.standing_classes')}: expected a list "
                              f"of class names ({CLASS_NAME_RULE}), got {classes!r}")
        values = {k: _number(doc, k, src, "detections", default=default[k])
                  for k in default if k != "standing_classes"}
        for k, v in values.items():
            if v < 0 or (k == "gate_sigmas" and v == 0):
                raise ConfigError(f"{where(src, 'detections.' + k)}: expected a number "
                                  f"{'> 0' if k == 'gate_sigmas' else '>= 0'}, got {v!r}")
        return cls(tuple(classes), **values)

    def geolocation(self) -> Geolocation:
        return Geolocation(tuple(self.standing_classes), math.radians(self.roll_sigma_deg),
                           math.radians(self.pitch_sigma_deg), math.radians(self.yaw_sigma_deg),
                           self.horizontal_sigma_m, self.vertical_sigma_m, self.pixel_sigma_px)


MAX_PEOPLE_PER_KM2 = 1e6
"""The most people per km^2 ``search.prior_people_per_km2`` takes: one per m^2."""


@dataclass(frozen=True, slots=True)
class SearchSection:
    """``search``: what the search assumes before any look: ``prior_people_per_km2``,
    people expected per km^2 where no POA map is given (the prior of a candidate's
    p_person, detection/candidates.py)."""

    prior_people_per_km2: float = 1.0

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> SearchSection:
        v = _number(doc, "prior_people_per_km2", src, "search",
                    default=_defaults(cls)["prior_people_per_km2"])
        if not 0 < v <= MAX_PEOPLE_PER_KM2:
            raise ConfigError(f"{where(src, 'search.prior_people_per_km2')}: expected a "
                              f"number > 0 and <= {MAX_PEOPLE_PER_KM2:g}, got {v!r}")
        return cls(v)


def _defaults(section: type) -> dict[str, Any]:
    """The default value of each field of a section dataclass that has one."""
    return {f.name: f.default for f in fields(section) if f.default is not MISSING}


_CAMERA_SECTIONS: dict[str, Section | Variants | None] = {
    "camera": CAMERA_CONFIG.extended(frame_rate_hz=None, exposure_s=None, calibration=None,
                                     zoom=None,
                                     zoom_lens=Section.of_dataclass(ZoomLensSection)),
    "mount": Variants("type", "fixed", {"fixed": Section.of_dataclass(FixedMountSection),
                                        "gimbal": GIMBAL_MOUNT_CONFIG}),
    "detector": MODEL_SCHEMA}
CAMERA_ENTRY = Section.of("name", **_CAMERA_SECTIONS)
"""One entry of the mission's ``cameras`` list: a name, and the camera, mount and detector
sections of the single-camera form."""

MISSION_CONFIG = Section.of(
    "vehicle_id", "calibration", "thresholds", "cameras",
    origin=Section.of_dataclass(OriginSection),
    domain=Section.of_dataclass(DomainSection),
    **_CAMERA_SECTIONS,
    coverage=Section.of_dataclass(CoverageSection),
    terrain=Section.of_dataclass(TerrainSection),
    log=Section.of_dataclass(LogSection),
    planning=Section.of_dataclass(PlanningSection),
    detections=Section.of_dataclass(DetectionsSection),
    search=Section.of_dataclass(SearchSection),
    **dict.fromkeys(RESERVED_SECTIONS, Section(open=True)))


def mission_schema(sections: Mapping[str, Section] | None = None) -> Section:
    """The keys of a mission config, every section and subsection (checked by
    ``mission_from_dict`` before any value is read).

    ``sections``: schemas of the reserved top-level sections ``link``, ``bus`` and
    ``service``, which belong to the onboard daemon: its modules declare them (a ``Section``,
    or a frozen dataclass per section through ``Section.of_dataclass(LinkConfig)``) and load
    the config with ``load_mission(path, sections={"link": LINK_CONFIG, ...})``; the section's
    mapping is then in ``Mission.raw["link"]`` for the daemon to build its values from. A
    reserved section without a schema here is accepted as any mapping (the offline tools do
    not read it).
    """
    sections = dict(sections or {})
    other = sorted(set(sections) - set(RESERVED_SECTIONS))
    if other:
        raise ValueError(f"only the reserved sections {RESERVED_SECTIONS} can be declared "
                         f"by another module, not {other}")
    return MISSION_CONFIG.extended(**sections)


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


def load_mission(path: str | Path, sections: Mapping[str, Section] | None = None) -> Mission:
    """Read and validate a mission config; relative paths inside resolve against its folder.
    ``sections``: schemas of the daemon's reserved sections (``mission_schema``)."""
    path = Path(path)
    doc = load_yaml(path, "mission config")
    return mission_from_dict(doc, source=str(path), base_dir=path.parent, sections=sections)


def mission_from_dict(doc: Any, source: str | None = None, base_dir: Path | None = None,
                      sections: Mapping[str, Section] | None = None) -> Mission:
    """Validate a parsed mission config mapping: first its keys, all sections
    (``mission_schema``), then the values."""
    src = source
    base = base_dir or Path(".")
    check_keys(doc, mission_schema(sections), src or "mission config")
    listed = _camera_list(doc, src)
    for key in ("origin", "domain", "camera", "detector"):
        if listed and key in ("camera", "detector"):
            continue
        if key not in doc and not (key == "camera" and "calibration" in doc):
            raise ConfigError(f"{where(src, key)}: missing (see docs/mission-config.md)")

    origin = OriginSection.from_mapping(_mapping(doc, "origin", src), src)
    try:
        origin_value = Origin(origin.lat_deg, origin.lon_deg, origin.ground_alt_msl_m or 0.0)
    except ConfigError as exc:
        raise ConfigError(f"{src}: {exc}" if src else str(exc)) from None

    dom = DomainSection.from_mapping(_mapping(doc, "domain", src), src)
    cell = dom.cell_size_m
    domain = _domain(dom, src, base, origin_value)
    ter = (TerrainSection.from_mapping(_mapping(doc, "terrain", src), src)
           if doc.get("terrain") is not None else None)
    dem = None
    ground_alt, ground_how, warnings = origin.ground_alt_msl_m, "configured", []
    if ter is not None:
        dem = _dem(ter, src, base, domain.grid_geometry(cell), origin_value)
        if ground_alt is None:
            ground_alt, ground_how = _dem_ground_alt(dem, origin, src), "the DEM at the origin"
            origin_value = Origin(origin.lat_deg, origin.lon_deg, ground_alt)
            domain = _domain(dom, src, base, origin_value)  # geodetic polygons at that ground
        elif err := dem_rules.home_offset_error(dem, origin.lat_deg, origin.lon_deg, ground_alt,
                                                ter.max_home_offset_m):
            raise ConfigError(f"{where(src, 'origin.ground_alt_msl_m')}: {err}")
        else:
            mismatch = height_mismatch(dem, origin.lat_deg, origin.lon_deg, ground_alt,
                                       ter.check_margin_m, "origin.ground_alt_msl_m")
            warnings += [f"{src}: {mismatch}" if src else mismatch] if mismatch else []
    if not domain.has_free_cell(domain.grid_geometry(cell)):
        raise ConfigError(
            f"{where(src, 'domain')}: no free cell to cover: no centre of a {cell:g} m cell "
            f"lies in the free space ({domain.free_space.area:.3g} m^2 of the polygon's "
            f"{domain.boundary.area:.3g} m^2); the obstacles cover the polygon, or it is "
            "narrower than a cell (domain.cell_size_m)")

    terrain = None
    if dem is not None:
        g = domain.grid_geometry(cell)
        try:
            terrain = terrain_surface(dem, g, origin_value, domain.free_mask(g))
        except PdcovError as exc:
            raise ConfigError(f"{where(src, 'terrain.dem')}: {exc}") from None
    cameras = ([_mission_camera(e, f"cameras[{i}].", str(e.get("name", f"camera{i + 1}")),
                                src, base) for i, e in enumerate(listed)]
               if listed else [_mission_camera(doc, "", "camera", src, base)])
    first = cameras[0]
    camera, rate, mount, detector, zoom, exposure = (
        first.camera, first.frame_rate_hz, first.mount, first.detector, first.zoom,
        first.exposure_s)

    thresholds = doc.get("thresholds", list(DEFAULT_THRESHOLDS))
    if (not isinstance(thresholds, list) or not thresholds or not all(
            isinstance(t, (int, float)) and not isinstance(t, bool) and 0 <= t <= 1
            for t in thresholds)):
        raise ConfigError(f"{where(src, 'thresholds')}: expected a non-empty list of "
                          f"probabilities in [0, 1], got {thresholds!r}")
    if len(thresholds) > MAX_THRESHOLDS:
        raise ConfigError(f"{where(src, 'thresholds')}: {len(thresholds)} thresholds, at "
                          f"most {MAX_THRESHOLDS} (every watcher refuses a status with more; "
                          "docs/protocol.md \"Validation and bounds\")")

    cov = CoverageSection.from_mapping(_mapping(doc, "coverage", src, required=False), src)
    det = DetectionsSection.from_mapping(_mapping(doc, "detections", src, required=False), src)
    search = SearchSection.from_mapping(_mapping(doc, "search", src, required=False), src)
    log_doc = _mapping(doc, "log", src, required=False)
    log = LogSection.from_mapping(log_doc, src)
    vehicle_id = doc.get("vehicle_id", "uav1")
    if not valid_vehicle_id(vehicle_id):
        raise ConfigError(f"{where(src, 'vehicle_id')}: expected {VEHICLE_ID_RULE}, "
                          f"got {vehicle_id!r}")
    if listed:
        for i, cam in enumerate(cameras):
            cov.looks_config(cam.detector, src, f"cameras[{i}].detector")
        _check_camera_ids(cameras, src)
    looks = cov.looks_config(detector, src)
    return Mission(
        vehicle_id=vehicle_id, origin_lat_deg=origin.lat_deg, origin_lon_deg=origin.lon_deg,
        ground_alt_msl_m=ground_alt,
        domain=domain, cell_size_m=cell, camera=camera, frame_rate_hz=rate, mount=mount,
        detector=detector, exposure_s=exposure, thresholds=tuple(float(t) for t in thresholds),
        max_range_m=cov.max_range_m, min_revisit_s=cov.min_revisit_s,
        min_height_m=cov.min_height_m, looks=looks,
        frame_source=log.frame_source, frame_source_set="frame_source" in log_doc,
        max_gap_s=log.max_gap_s, system_id=log.system_id,
        estimator_status=log.estimator_status, ground_alt_how=ground_how, terrain=terrain,
        dem=dem, terrain_check_margin_m=ter.check_margin_m if ter else DEFAULT_TERRAIN_MARGIN_M,
        terrain_max_home_offset_m=(ter.max_home_offset_m if ter
                                   else dem_rules.DEFAULT_MAX_HOME_OFFSET_M),
        geolocation=det.geolocation(), gate_sigmas=det.gate_sigmas,
        prior_people_per_km2=search.prior_people_per_km2,
        warnings=tuple(warnings), zoom=zoom, extra_cameras=tuple(cameras[1:]),
        camera_name=first.name, source=src, raw=doc)


def _mapping(doc: Mapping[str, Any], key: str, src: str | None,
             required: bool = True) -> Mapping[str, Any]:
    v = doc.get(key)
    if v is None and not required:
        return {}
    if not isinstance(v, dict):
        raise ConfigError(f"{where(src, key)}: expected a mapping, got {v!r}")
    return v


def _number(doc: Mapping[str, Any], key: str, src: str | None, section: str,
            default: float | None = None, positive: bool = False) -> float:
    full = f"{section}.{key}"
    v = doc.get(key, default)
    if v is None:
        raise ConfigError(f"{where(src, full)}: missing (a number)")
    # abs(v) <= max float: false for NaN, infinities and integers a float cannot hold
    # (math.isfinite raises OverflowError on those).
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not abs(v) <= _FLOAT_MAX:
        raise ConfigError(f"{where(src, full)}: expected a finite number, got {v!r}")
    if positive and v <= 0:
        raise ConfigError(f"{where(src, full)}: expected a positive number, got {v!r}")
    return float(v)


def _opt_number(doc: Mapping[str, Any], key: str, src: str | None, section: str
                ) -> float | None:
    return None if doc.get(key) is None else _number(doc, key, src, section, positive=True)


def _domain(dom: DomainSection, src: str | None, base: Path, origin: Origin) -> Domain:
    forms = [k for k in ("polygon_enu_m", "polygon_geodetic_deg", "geojson")
             if getattr(dom, k) is not None]
    if len(forms) != 1:
        raise ConfigError(f"{where(src, 'domain')}: expected exactly one of polygon_enu_m, "
                          f"polygon_geodetic_deg or geojson, got {forms or 'none'}")
    try:
        if forms[0] == "polygon_enu_m":
            return Domain.from_enu(dom.polygon_enu_m, dom.obstacles_enu_m, src)
        if forms[0] == "polygon_geodetic_deg":
            return Domain.from_geodetic(dom.polygon_geodetic_deg, dom.obstacles_geodetic_deg,
                                        origin, src)
        return Domain.from_geojson(_resolve(dom.geojson, base, src, "domain.geojson"), origin)
    except PdcovError as exc:
        raise ConfigError(str(exc)) from None


def _dem(ter: TerrainSection, src: str | None, base: Path, g: GridGeometry,
         origin: Origin) -> Dem:
    """The DEM, read over the grid and the origin (``Dem.open``'s margin around them)."""
    path = _resolve(ter.dem, base, src, "terrain.dem")
    x1, y1 = g.x0_m + g.cell_size_m * g.n_cols, g.y0_m + g.cell_size_m * g.n_rows
    corners = np.array([[g.x0_m, g.y0_m, 0.0], [x1, g.y0_m, 0.0], [x1, y1, 0.0],
                        [g.x0_m, y1, 0.0]])
    geo = enu_to_geodetic(corners, origin)
    lat = np.append(geo[:, 0], origin.lat_deg)
    lon = np.append(geo[:, 1], origin.lon_deg)
    try:
        return Dem.open(path, vertical_datum=ter.vertical_datum,
                        geoid_height_m=ter.geoid_height_m,
                        area_lonlat_deg=(lon.min(), lat.min(), lon.max(), lat.max()))
    except PdcovError as exc:
        raise ConfigError(f"{where(src, 'terrain.dem')}: {exc}") from None


def _dem_ground_alt(dem: Dem, origin: OriginSection, src: str | None) -> float:
    """The DEM's height (m MSL) at the origin, for an origin.ground_alt_msl_m not given."""
    h = float(dem.height_msl_m(origin.lat_deg, origin.lon_deg))
    if not math.isfinite(h):
        raise ConfigError(f"{where(src, 'terrain.dem')}: {dem.path}: no height at the origin "
                          f"({origin.lat_deg:.6f}, {origin.lon_deg:.6f}): it is outside the "
                          "DEM or on nodata; set origin.ground_alt_msl_m")
    return h


def _camera_list(doc: Mapping[str, Any], src: str | None) -> list[Mapping[str, Any]]:
    """The ``cameras`` list's entries, keys checked (empty without one)."""
    listed = doc.get("cameras")
    if listed is None:
        return []
    if not isinstance(listed, list) or not listed:
        raise ConfigError(f"{where(src, 'cameras')}: expected a non-empty list of cameras "
                          f"(name, camera, mount, detector), got {listed!r}")
    both = sorted({"camera", "mount", "detector", "calibration"} & set(doc))
    if both:
        raise ConfigError(f"{where(src, both[0])}: not allowed with a cameras list (give each "
                          "camera's camera, mount and detector in its entry)")
    names = []
    for i, entry in enumerate(listed):
        check_keys(entry, CAMERA_ENTRY, src, f"cameras[{i}]")
        name = entry.get("name", f"camera{i + 1}")
        if not valid_vehicle_id(name) or name in names:
            raise ConfigError(f"{where(src, f'cameras[{i}].name')}: expected a unique name "
                              f"({VEHICLE_ID_RULE}), got {name!r}")
        names.append(name)
        for key in ("camera", "detector"):
            if key not in entry:
                raise ConfigError(f"{where(src, f'cameras[{i}].{key}')}: missing")
    return listed


MAVLINK_CAMERA_COMPONENTS = range(100, 106)
"""MAV_COMP_ID_CAMERA .. MAV_COMP_ID_CAMERA6: a MAVLink camera's own component."""


def _check_camera_ids(cameras: list[MissionCamera], src: str | None) -> None:
    """In a cameras list, each zoom camera names the camera whose reports it follows
    (zoom_lens.component_id: 100-105 for a MAVLink camera, camera_device_id 0; any with an
    autopilot-attached camera, camera_device_id 1-6), no two the same; and cameras on one
    gimbal device (mount.instance) read it alike (their mounts differ at most in the lever
    arm)."""
    followed: dict[tuple[int, int], int] = {}
    gimbals: dict[int, tuple[int, GimbalMount]] = {}
    for i, cam in enumerate(cameras):
        lens_at = where(src, f"cameras[{i}].camera.zoom_lens.component_id")
        if cam.zoom is not None:
            ident = cam.zoom.camera_id
            if ident is None:
                raise ConfigError(f"{lens_at}: missing: with a cameras list each zoom camera "
                                  "names the camera component whose reports it follows "
                                  "(100-105 for a MAVLink camera)")
            if ident[1] == 0 and ident[0] not in MAVLINK_CAMERA_COMPONENTS:
                raise ConfigError(f"{lens_at}: expected a MAVLink camera component 100..105 "
                                  f"(camera_device_id 0), got {ident[0]}")
            if ident in followed:
                raise ConfigError(f"{lens_at}: component {ident[0]}, camera_device_id "
                                  f"{ident[1]} is also cameras[{followed[ident]}]'s: each "
                                  "camera follows its own reports")
            followed[ident] = i
        if isinstance(cam.mount, GimbalMount):
            bare = dataclasses.replace(cam.mount, lever_arm_frd_m=(0.0, 0.0, 0.0))
            other = gimbals.setdefault(cam.mount.instance, (i, bare))
            if other[1] != bare:
                raise ConfigError(
                    f"{where(src, f'cameras[{i}].mount')}: gimbal device "
                    f"{cam.mount.instance} (mount.instance) is also cameras[{other[0]}]'s, "
                    "with other settings: cameras on one gimbal read it alike (only "
                    "lever_arm_frd_m may differ); give this camera's gimbal its own instance")


def _mission_camera(entry: Mapping[str, Any], at: str, name: str, src: str | None,
                    base: Path) -> MissionCamera:
    """One camera from a ``cameras`` entry (``at``: its key path, e.g. 'cameras[1].'), or
    from the single-camera form's top-level camera, mount and detector (``at`` '')."""
    try:
        camera, rate, exposure = _camera(entry, src, base)
        zoom = _zoom(entry.get("camera", {}), camera, src)
        mount = _mount(entry.get("mount", {"type": "fixed"}), src)
        detector = _detector(entry["detector"], src, base)
    except ConfigError as exc:
        if not at:
            raise
        text, lead = str(exc), f"{src}: " if src else ""
        if not text.startswith(lead):
            raise
        raise type(exc)(f"{lead}{at}{text[len(lead):]}") from None
    return MissionCamera(name, camera, rate, mount, detector, zoom, exposure)


def _camera(doc: Mapping[str, Any], src: str | None, base: Path
            ) -> tuple[CameraModel, float, float | None]:
    """The camera model, camera.frame_rate_hz and camera.exposure_s (None: not given)."""
    cam = doc.get("camera", {})
    if not isinstance(cam, dict):
        raise ConfigError(f"{where(src, 'camera')}: expected a mapping, got {cam!r}")
    calibration = cam.get("calibration", doc.get("calibration"))
    if calibration is not None:
        extra = sorted(set(cam) & set(CAMERA_CONFIG.keys))
        if extra:
            raise ConfigError(f"{where(src, 'camera.' + extra[0])}: not allowed with a "
                              f"calibration file (give the intrinsics in one place)")
        camera = CameraModel.from_camera_info(_resolve(calibration, base, src, "calibration"))
    else:
        inline = {k: v for k, v in cam.items()
                  if k not in ("frame_rate_hz", "exposure_s", "zoom", "zoom_lens")}
        camera = CameraModel.from_config(inline, src, "camera")
    rate = _number(cam, "frame_rate_hz", src, "camera", positive=True)
    if rate > MAX_FRAME_RATE_HZ:
        raise ConfigError(f"{where(src, 'camera.frame_rate_hz')}: {rate:g} Hz, more than the "
                          f"{MAX_FRAME_RATE_HZ:g} Hz a camera frames at")
    return camera, rate, _opt_number(cam, "exposure_s", src, "camera")


def _zoom(cam: Mapping[str, Any], camera: CameraModel, src: str | None) -> Zoom | None:
    """camera.zoom (none, fov_status, table) and camera.zoom_lens."""
    mode = cam.get("zoom", "none")
    if mode not in ZOOM_MODES:
        raise ConfigError(f"{where(src, 'camera.zoom')}: expected one of "
                          f"{', '.join(ZOOM_MODES)}, got {mode!r}")
    lens_doc = cam.get("zoom_lens") or {}
    if not isinstance(lens_doc, dict):
        raise ConfigError(f"{where(src, 'camera.zoom_lens')}: expected a mapping, got "
                          f"{lens_doc!r}")
    if mode == "none":
        if lens_doc:
            raise ConfigError(f"{where(src, 'camera.zoom_lens')}: given with camera.zoom none; "
                              "set camera.zoom to fov_status or table, or remove it")
        return None
    return ZoomLensSection.from_mapping(lens_doc, src).zoom(mode, camera, src)


def _mount(doc: Any, src: str | None) -> FixedMount | GimbalMount:
    if not isinstance(doc, dict):
        raise ConfigError(f"{where(src, 'mount')}: expected a mapping, got {doc!r}")
    kind = doc.get("type", "fixed")
    if kind == "gimbal":
        return GimbalMount.from_config(doc, src)
    if kind != "fixed":
        raise ConfigError(f"{where(src, 'mount.type')}: expected 'fixed' or 'gimbal', "
                          f"got {kind!r}")
    check_keys(doc, Section.of_dataclass(FixedMountSection), src, "mount")
    return FixedMountSection.from_mapping(doc, src).mount()


def _detector(v: Any, src: str | None, base: Path) -> DetectorModel:
    if isinstance(v, str):
        if v == "illustrative":
            return DetectorModel.illustrative()
        return DetectorModel.from_yaml(_resolve(v, base, src, "detector"))
    if isinstance(v, dict):
        return DetectorModel.from_dict(v, source=where(src, "detector"))
    raise ConfigError(f"{where(src, 'detector')}: expected a path to a detector model YAML, "
                      f"'illustrative', or an inline model mapping, got {v!r}")


def _resolve(v: Any, base: Path, src: str | None, key: str) -> Path:
    if not isinstance(v, str) or not v:
        raise ConfigError(f"{where(src, key)}: expected a file path, got {v!r}")
    p = Path(v).expanduser()
    p = p if p.is_absolute() else base / p
    if not p.is_file():
        raise ConfigError(f"{where(src, key)}: file not found: {p}")
    return p
