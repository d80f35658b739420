"""A camera's calibration as files give it: the mission config's ``camera`` section and a ROS
``camera_info`` YAML, checked key by key and read into ``CameraModel``'s constructor
arguments (core/camera.py validates the values themselves).

``CameraConfig`` is the mission config's section, its fields the keys (``CAMERA_CONFIG``,
read by pdcov/schema.py); ``CAMERA_INFO`` lists the keys of the ROS format. Both readers
return a ``CameraConfig``, raising ``CalibrationError`` naming the file and key.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.errors import CalibrationError, where
from pdcov.schema import Section, check_keys
from pdcov.yaml_file import load_yaml

__all__ = ["CAMERA_CONFIG", "CAMERA_INFO", "CameraConfig", "camera_config_from_camera_info",
           "camera_config_from_mapping"]


@dataclass(frozen=True, slots=True)
class CameraConfig:
    """The ``camera`` section as read: sizes (px), K (3x3), the distortion model and its
    coefficients. The values are CameraModel's to validate (sizes and model may be any YAML
    value here)."""

    width_px: Any
    height_px: Any
    K: np.ndarray
    distortion_model: Any = "plumb_bob"
    distortion_coeffs: np.ndarray | tuple[float, ...] = ()

CAMERA_CONFIG = Section.of_dataclass(CameraConfig)
# The keys of a ROS camera_info file (as camera_calibration and camera_info_manager write it;
# rectification and projection are read by nothing here but belong to the format).
_ROS_MATRIX = Section.of("rows", "cols", "data")
CAMERA_INFO = Section.of("image_width", "image_height", "camera_name", "distortion_model",
                         camera_matrix=_ROS_MATRIX, distortion_coefficients=_ROS_MATRIX,
                         rectification_matrix=_ROS_MATRIX, projection_matrix=_ROS_MATRIX)


def camera_config_from_mapping(doc: Any, source: str | None = None, key: str = "camera"
                               ) -> CameraConfig:
    """From a mission-config mapping: width_px, height_px, K, distortion_model,
    distortion_coeffs. ``source``: the file; ``key``: the section's key path in it."""
    if not isinstance(doc, dict):
        raise CalibrationError(f"{where(source, key)}: expected a mapping")
    check_keys(doc, CAMERA_CONFIG, source, key, CalibrationError)
    for k in ("width_px", "height_px", "K"):
        if k not in doc:
            raise CalibrationError(f"{where(source, key + '.' + k)}: missing")
    return CameraConfig(doc["width_px"], doc["height_px"], _matrix(doc["K"], source, key + ".K"),
                        doc.get("distortion_model", "plumb_bob"),
                        _floats(doc.get("distortion_coeffs", []), source,
                                key + ".distortion_coeffs"))


def camera_config_from_camera_info(path: str | Path) -> CameraConfig:
    """From a ROS ``camera_info`` YAML (image_width, image_height, camera_matrix,
    distortion_model, distortion_coefficients) as camera_calibration writes it."""
    doc = load_yaml(path, "camera calibration", CalibrationError)
    src = str(path)
    if not isinstance(doc, dict):
        raise CalibrationError(f"{src}: expected a camera_info mapping")
    check_keys(doc, CAMERA_INFO, src, "", CalibrationError)
    for k in ("image_width", "image_height", "camera_matrix"):
        if k not in doc:
            raise CalibrationError(f"{where(src, k)}: missing")
    K = _ros_matrix(doc["camera_matrix"], src, "camera_matrix", 9)
    dist = doc.get("distortion_coefficients")
    coeffs = (_ros_matrix(dist, src, "distortion_coefficients", None)
              if dist is not None else np.zeros(5))
    return CameraConfig(doc["image_width"], doc["image_height"], K.reshape(3, 3),
                        doc.get("distortion_model", "plumb_bob"), coeffs)


def _floats(v: Any, source: str | None, key: str) -> np.ndarray:
    """A flat list of numbers as floats (an integer too large for a float is refused)."""
    if not isinstance(v, (list, tuple)) or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        raise CalibrationError(f"{where(source, key)}: expected a list of numbers, got {v!r}")
    try:
        return np.array([float(x) for x in v], dtype=float)
    except OverflowError:
        raise CalibrationError(f"{where(source, key)}: a number too large, got {v!r}") from None


def _matrix(v: Any, source: str | None, key: str) -> np.ndarray:
    """K as 3 rows of 3 numbers: [[fx, s, cx], [0, fy, cy], [0, 0, 1]]."""
    if not isinstance(v, (list, tuple)) or len(v) != 3:
        raise CalibrationError(f"{where(source, key)}: expected 3 rows of 3 numbers "
                               f"[[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {v!r}")
    rows = [_floats(row, source, key) for row in v]
    for i, row in enumerate(rows):
        if row.size != 3:
            raise CalibrationError(f"{where(source, key)}: expected 3 rows of 3 numbers, "
                                   f"row {i + 1} has {row.size}")
    return np.array(rows)


def _ros_matrix(v: Any, source: str, key: str, size: int | None) -> np.ndarray:
    data = v.get("data") if isinstance(v, dict) else v
    arr = _floats(data, source, key + ".data")
    if size is not None and arr.size != size:
        raise CalibrationError(f"{where(source, key)}: expected {size} values, got {arr.size}")
    return arr
