"""The mission config's ``detections`` section: how the detector's boxes are geolocated
(1-sigma attitude errors in deg, position in m, pixel in px) and grouped."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pdcov.config.values import defaults, number
from pdcov.core.detections import CLASS_NAME_RULE, valid_class_name
from pdcov.core.geolocate import Geolocation
from pdcov.errors import ConfigError, where


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
        default = defaults(cls)
        classes = doc.get("standing_classes", list(default["standing_classes"]))
        if not isinstance(classes, list) or not all(valid_class_name(c) for c in classes):
            raise ConfigError(f"{where(src, 'detections.standing_classes')}: expected a list "
                              f"of class names ({CLASS_NAME_RULE}), got {classes!r}")
        values = {k: number(doc, k, src, "detections", default=default[k])
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
