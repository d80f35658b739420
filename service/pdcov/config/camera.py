"""One camera of the mission config: its ``camera`` (intrinsics or a calibration file, frame
rate, exposure, ``zoom`` and ``zoom_lens``), ``mount`` (fixed or a gimbal) and ``detector``
sections, at the top level or in an entry of the ``cameras`` list."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pdcov.config.mission import MissionCamera
from pdcov.config.values import FLOAT_MAX, defaults, number, opt_number, resolve
from pdcov.core.camera import CameraModel
from pdcov.core.camera_config import CAMERA_CONFIG
from pdcov.core.detector import MODEL_SCHEMA, DetectorModel
from pdcov.core.mount import GIMBAL_MOUNT_CONFIG, GimbalMount
from pdcov.core.pose import FixedMount
from pdcov.core.zoom import FovLens, LensQuantity, TableLens, Zoom, ZoomLens
from pdcov.errors import CalibrationError, ConfigError, where
from pdcov.schema import Section, Variants, check_keys

MAX_FRAME_RATE_HZ = 1000.0  # camera.frame_rate_hz beyond: a typo (memory: serve --check)


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
        default = defaults(cls)
        angles = {k: number(doc, k, src, "mount", default=default[k])
                  for k in ("roll_deg", "pitch_deg", "yaw_deg")}
        arm = doc.get("lever_arm_frd_m", [0.0, 0.0, 0.0])
        if (not isinstance(arm, list) or len(arm) != 3 or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) <= FLOAT_MAX
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
        default = defaults(cls)
        nums = {k: number(doc, k, src, sec, default=default[k], positive=True)
                for k in ("max_zoom_rate_per_s", "max_report_age_s")}
        tol = number(doc, "fov_tolerance_deg", src, sec, default=1.0)
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
        return cls(opt_number(doc, "min_hfov_deg", src, sec), tol, **nums,
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
            keys.append(number(row, self.table_by, src, at))
            cams.append(CameraModel.from_config(
                {"width_px": camera.width_px, "height_px": camera.height_px,
                 "distortion_model": camera.distortion_model,
                 "distortion_coeffs": row.get("distortion_coeffs",
                                              camera.dist_coeffs.tolist()),
                 "K": row.get("K")}, src, at))
        return TableLens(LensQuantity(self.table_by), tuple(keys), tuple(cams),
                         self.max_zoom_rate_per_s, where(src, sec))


CAMERA_SECTIONS: dict[str, Section | Variants | None] = {
    "camera": CAMERA_CONFIG.extended(frame_rate_hz=None, exposure_s=None, calibration=None,
                                     zoom=None,
                                     zoom_lens=Section.of_dataclass(ZoomLensSection)),
    "mount": Variants("type", "fixed", {"fixed": Section.of_dataclass(FixedMountSection),
                                        "gimbal": GIMBAL_MOUNT_CONFIG}),
    "detector": MODEL_SCHEMA}
"""The schemas of one camera's sections (keys checked before any value is read)."""


def mission_camera(entry: Mapping[str, Any], at: str, name: str, src: str | None,
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
        camera = CameraModel.from_camera_info(resolve(calibration, base, src, "calibration"))
    else:
        inline = {k: v for k, v in cam.items()
                  if k not in ("frame_rate_hz", "exposure_s", "zoom", "zoom_lens")}
        camera = CameraModel.from_config(inline, src, "camera")
    rate = number(cam, "frame_rate_hz", src, "camera", positive=True)
    if rate > MAX_FRAME_RATE_HZ:
        raise ConfigError(f"{where(src, 'camera.frame_rate_hz')}: {rate:g} Hz, more than the "
                          f"{MAX_FRAME_RATE_HZ:g} Hz a camera frames at")
    return camera, rate, opt_number(cam, "exposure_s", src, "camera")


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
        return DetectorModel.from_yaml(resolve(v, base, src, "detector"))
    if isinstance(v, dict):
        return DetectorModel.from_dict(v, source=where(src, "detector"))
    raise ConfigError(f"{where(src, 'detector')}: expected a path to a detector model YAML, "
                      f"'illustrative', or an inline model mapping, got {v!r}")
