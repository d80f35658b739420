"""A zoom lens: the camera model of a frame from the zoom report in force at its time.

The paper's method "can account for controlled changes to the camera parameters, for example,
by zooming, as long as the camera's parameters are known at the time of capturing the image".
A ``ZoomLens`` maps one reported quantity (``LensQuantity``) to a ``CameraModel``:

* ``FovLens`` follows CAMERA_FOV_STATUS.hfov (common.xml: horizontal field of view, deg; the
  adapter gives rad). The configured calibration is the widest zoom's; at a reported field of
  view ``hfov`` the focal lengths (fx, fy and the skew) scale by
  ``tan(hfov_wide / 2) / tan(hfov / 2)`` with ``hfov_wide = 2 atan((w / 2) / fx)`` of the
  configured K, i.e. f = (w / 2) / tan(hfov / 2) relative to the configured one. The
  principal point and the distortion coefficients stay the configured ones. An
  approximation: a real zoom lens moves its principal point and changes its distortion with
  the zoom; calibrate it at several zoom levels (``TableLens``) where that matters.
* ``TableLens`` interpolates a calibration table: K and distortion at several zoom levels
  (CAMERA_SETTINGS.zoomLevel) or focal lengths (CAMERA_INFORMATION.focal_length, mm),
  linearly in focal length (fx) between the two calibrated entries around the report.

A report outside the calibrated range gives no camera: ``refusal`` says why, and the frame is
skipped (telemetry/frame_policy.SkipReason), never evaluated with a wrong K. Cameras are built
once per distinct reported value (a zoom report repeats its value while the lens is still),
at most _CACHE_SIZE kept (least recently used out); a field of view is first quantised to a
FOV_FOCAL_STEP step of ln(focal length) (``quantised_hfov_rad``), so that a report jittering
by 0.01 deg (a camera's rounding) reuses a camera instead of building one per frame (0.14 s
each, 71 % of a core at 5 Hz).
"""

from __future__ import annotations

import enum
import math
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from pdcov.core.camera import CameraModel
from pdcov.errors import CalibrationError

_CACHE_SIZE = 128  # cameras kept per lens (distinct reported values)
FOV_FOCAL_STEP = 2e-4
"""Step of ln(focal length) a reported field of view is quantised to: the focal length moves
by at most 1e-4 of itself, 0.1 px at the edge of a 1920 px picture (tests/unit/test_zoom.py
shows the grids agree); 0.01 deg of jitter at 60 deg spans two steps."""


class LensQuantity(str, enum.Enum):
    """The reported quantity a lens follows, and its unit."""

    HFOV_RAD = "hfov_rad"  # CAMERA_FOV_STATUS.hfov
    ZOOM_LEVEL = "zoom_level"  # CAMERA_SETTINGS.zoomLevel (0..100 %, or the camera's steps)
    FOCAL_LENGTH_MM = "focal_length_mm"  # CAMERA_INFORMATION.focal_length

    def __str__(self) -> str:
        return str(self.value)


def hfov_rad(camera: CameraModel) -> float:
    """The pinhole horizontal field of view (rad) of a camera's K: 2 atan((w / 2) / fx)."""
    return 2.0 * math.atan((camera.width_px / 2) / float(camera.K[0, 0]))


def quantised_hfov_rad(hfov: float, wide_rad: float) -> float:
    """``hfov`` (rad) with ln(tan(hfov / 2)), i.e. -ln(focal length) + const, rounded to a
    multiple of FOV_FOCAL_STEP; ``wide_rad`` and wider unchanged (the configured camera)."""
    if not hfov < wide_rad:
        return hfov
    u = round(math.log(math.tan(hfov / 2)) / FOV_FOCAL_STEP) * FOV_FOCAL_STEP
    return min(2.0 * math.atan(math.exp(u)), wide_rad)


@dataclass(frozen=True, slots=True)
class _Cache:
    cameras: OrderedDict[float, CameraModel] = field(default_factory=OrderedDict)

    def get(self, value: float, build: object) -> CameraModel:
        found = self.cameras.get(value)
        if found is None:
            found = build(value)  # type: ignore[operator]
            self.cameras[value] = found
            if len(self.cameras) > _CACHE_SIZE:
                self.cameras.popitem(last=False)
        else:
            self.cameras.move_to_end(value)
        return found


@dataclass(frozen=True, slots=True)
class FovLens:
    """A zoom followed by its reported horizontal field of view (module docstring).

    wide: the configured camera (the widest zoom). min_hfov_rad: the narrowest field of view
    the lens reaches (rad). tolerance_rad: a report this much wider than the configured
    camera's is taken as the widest zoom (cameras round their report); wider, or narrower than
    min_hfov_rad by as much, is refused. max_rate_per_s: the fastest the lens zooms, as
    |d ln(focal length) / dt| (1/s): a report implying a faster change than that from the one
    before is a jump (``telemetry/lens_reports.py``)."""

    wide: CameraModel
    min_hfov_rad: float
    tolerance_rad: float = math.radians(1.0)
    max_rate_per_s: float = 2.0
    _cache: _Cache = field(default_factory=_Cache, compare=False, repr=False)

    quantity = LensQuantity.HFOV_RAD

    def __post_init__(self) -> None:
        wide = hfov_rad(self.wide)
        if not (0 < self.min_hfov_rad <= wide):
            raise CalibrationError(
                f"camera.zoom_lens.min_hfov_deg: expected a field of view in (0, "
                f"{math.degrees(wide):.3f}] deg (the configured K's, the widest zoom), got "
                f"{math.degrees(self.min_hfov_rad):g}")
        if not (self.tolerance_rad >= 0 and self.max_rate_per_s > 0):
            raise CalibrationError("camera.zoom_lens: fov_tolerance_deg must be >= 0 and "
                                   f"max_zoom_rate_per_s > 0, got {self.tolerance_rad!r}, "
                                   f"{self.max_rate_per_s!r}")

    def refusal(self, value: float) -> str:
        """'' when a reported hfov (rad) is within the calibrated range, else why not."""
        wide = hfov_rad(self.wide)
        if not math.isfinite(value):
            return "no field of view in the report (NaN)"
        if value > wide + self.tolerance_rad or value < self.min_hfov_rad - self.tolerance_rad:
            return (f"reported field of view {math.degrees(value):.2f} deg outside the "
                    f"calibrated {math.degrees(self.min_hfov_rad):.2f}-"
                    f"{math.degrees(wide):.2f} deg")
        return ""

    def focal_px(self, value: np.ndarray) -> np.ndarray:
        """fx (px) at reported hfovs (rad), clamped to the calibrated range."""
        wide = hfov_rad(self.wide)
        h = np.clip(np.asarray(value, float), self.min_hfov_rad, wide)
        return float(self.wide.K[0, 0]) * math.tan(wide / 2) / np.tan(h / 2)

    def camera(self, value: float) -> CameraModel:
        """The camera at a reported hfov (rad) that ``refusal`` accepts, quantised
        (``quantised_hfov_rad``)."""
        return self._cache.get(quantised_hfov_rad(float(value), hfov_rad(self.wide)),
                               self._build)

    def _build(self, value: float) -> CameraModel:
        w = self.wide
        scale = float(self.focal_px(np.array(value))) / float(w.K[0, 0])
        if scale == 1.0:
            return w
        K = w.K.copy()
        K[0, :2] *= scale  # fx and the skew
        K[1, 1] *= scale
        return CameraModel(w.width_px, w.height_px, K, w.distortion_model,
                           np.array(w.dist_coeffs), source=w.source)


@dataclass(frozen=True, slots=True)
class TableLens:
    """A zoom calibrated at several settings: ``keys`` (increasing zoom levels or focal lengths
    in mm, of ``quantity``) and the camera calibrated at each (same size and distortion
    model; focal length increasing with the key). Between two entries K and the distortion
    coefficients are interpolated linearly in fx; the key maps to fx linearly between them.
    Reports outside [keys[0], keys[-1]] are refused."""

    quantity: LensQuantity
    keys: tuple[float, ...]
    cameras: tuple[CameraModel, ...]
    max_rate_per_s: float = 2.0
    source: str = "camera.zoom_lens.table"
    _cache: _Cache = field(default_factory=_Cache, compare=False, repr=False)

    def __post_init__(self) -> None:
        src = self.source
        if self.quantity == LensQuantity.HFOV_RAD:
            raise CalibrationError(f"{src}: a table follows zoom_level or focal_length_mm")
        if len(self.keys) != len(self.cameras) or len(self.keys) < 2:
            raise CalibrationError(f"{src}: expected at least two entries, got "
                                   f"{len(self.keys)}")
        keys = np.asarray(self.keys, float)
        if not (np.all(np.isfinite(keys)) and np.all(np.diff(keys) > 0)):
            raise CalibrationError(f"{src}: {self.quantity} must increase strictly from entry "
                                   f"to entry, got {list(self.keys)}")
        fx = np.array([c.K[0, 0] for c in self.cameras])
        if not np.all(np.diff(fx) > 0):
            raise CalibrationError(f"{src}: the focal length K[0][0] must increase with "
                                   f"{self.quantity} (a zoom table is monotonic), got "
                                   f"{fx.tolist()}")
        first = self.cameras[0]
        for i, c in enumerate(self.cameras):
            if (c.width_px, c.height_px, c.distortion_model, c.dist_coeffs.size) != (
                    first.width_px, first.height_px, first.distortion_model,
                    first.dist_coeffs.size):
                raise CalibrationError(f"{src}[{i}]: every entry needs the size and the "
                                       "distortion model (and coefficient count) of the first")
        if not self.max_rate_per_s > 0:
            raise CalibrationError(f"{src}: max_zoom_rate_per_s must be > 0")

    @property
    def wide(self) -> CameraModel:
        return self.cameras[0]

    def refusal(self, value: float) -> str:
        if not math.isfinite(value):
            return f"no {self.quantity} in the report"
        if not (self.keys[0] <= value <= self.keys[-1]):
            return (f"reported {self.quantity} {value:g} outside the calibrated "
                    f"{self.keys[0]:g}-{self.keys[-1]:g}")
        return ""

    def focal_px(self, value: np.ndarray) -> np.ndarray:
        fx = np.array([c.K[0, 0] for c in self.cameras])
        return np.interp(np.asarray(value, float), self.keys, fx)

    def camera(self, value: float) -> CameraModel:
        return self._cache.get(float(value), self._build)

    def _build(self, value: float) -> CameraModel:
        i = int(np.searchsorted(self.keys, value, side="right")) - 1
        i = min(max(i, 0), len(self.keys) - 2)
        a, b = self.cameras[i], self.cameras[i + 1]
        f = float(self.focal_px(np.array(value)))
        w = (f - a.K[0, 0]) / (b.K[0, 0] - a.K[0, 0])
        if w <= 0.0:
            return a
        if w >= 1.0:
            return b
        K = (1 - w) * a.K + w * b.K
        K[0, 0] = f  # exactly the interpolated focal length
        d = (1 - w) * a.dist_coeffs + w * b.dist_coeffs
        return CameraModel(a.width_px, a.height_px, K, a.distortion_model, d, source=a.source)


ZoomLens = FovLens | TableLens


def jumps(t_s: np.ndarray, focal_px: np.ndarray, max_rate_per_s: float) -> np.ndarray:
    """Per report (time order), True where its focal length differs from the previous report's
    faster than the lens can zoom: |ln f_k - ln f_(k-1)| > max_rate_per_s (t_k - t_(k-1))
    (+ 1e-6 for rounding). The first report is no jump."""
    t = np.asarray(t_s, float)
    ln_f = np.log(np.asarray(focal_px, float))
    out = np.zeros(len(t), bool)
    if len(t) > 1:
        out[1:] = np.abs(np.diff(ln_f)) > max_rate_per_s * np.diff(t) + 1e-6
    return out



@dataclass(frozen=True, slots=True)
class Zoom:
    """The mission's zoom: the lens, how long a report stays in force (s) and which camera's
    reports count ((component_id, camera_device_id); None: the first camera heard)."""

    lens: ZoomLens
    max_report_age_s: float = 2.0
    camera_id: tuple[int, int] | None = None
