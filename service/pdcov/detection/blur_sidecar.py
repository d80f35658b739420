"""Motion blur per image of a labelled test set, read from a sidecar CSV
(docs/detector-statistics.md "Motion blur").

A header row, then one row per image: ``image`` (an image id, file name or file stem of the
ground truth) and either ``blur_px``, the blur length in that image's pixels, or
``speed_m_s`` and ``height_m``, the camera's ground speed and height above the ground when
the image was taken. A speed becomes a blur by the rule of a nadir camera moving straight
and level (core/blur.py's hand check), blur_px = focal_px * speed_m_s * exposure_s /
height_m, with the camera's focal length (px) and exposure time (s) given once for the set:
P_D is binned by blur, never by speed, because the coverage kernel computes each cell's blur
from the geometry of the flight (height, speed, turn rate, where in the picture), and a
speed bin would hold only at the test set's height and camera.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

from pdcov.detection.truth_set import TruthSet
from pdcov.errors import ConfigError, InputFileError

_BLUR = ("image", "blur_px")
_SPEED = ("image", "speed_m_s", "height_m")


@dataclass(frozen=True, slots=True)
class SpeedToBlur:
    """The set's camera for a speed column: focal length (px), exposure time (s)."""

    focal_px: float
    exposure_s: float

    def __post_init__(self) -> None:
        for key, v in (("--focal-px", self.focal_px), ("--exposure-s", self.exposure_s)):
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{key}: expected a positive number, got {v}")

    def blur_px(self, speed_m_s: float, height_m: float) -> float:
        return self.focal_px * speed_m_s * self.exposure_s / height_m


def read_blur_csv(path: Path, truth: TruthSet, speed: SpeedToBlur | None = None
                  ) -> dict[str, float]:
    """Blur (image px) by image id of ``truth``, for every image of it. Raises
    InputFileError naming the file and line of a bad row (unknown or repeated image, a
    value not a finite number >= 0, a height <= 0), ConfigError for a speed column without
    ``speed``, and InputFileError listing images without a row."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: cannot read the blur CSV ({exc})") from None
    rows = csv.reader(text.splitlines())
    header = tuple(h.strip() for h in next(rows, []))
    if header not in (_BLUR, _SPEED):
        raise InputFileError(f"{path}:1: expected the header {','.join(_BLUR)} or "
                             f"{','.join(_SPEED)}, got {','.join(header)!r}")
    if header == _SPEED and speed is None:
        raise ConfigError(f"{path}: a speed_m_s column becomes blur with the camera's focal "
                          "length and exposure time: give --focal-px and --exposure-s")
    if header == _BLUR and speed is not None:
        raise ConfigError(f"{path}: --focal-px and --exposure-s turn a speed_m_s column into "
                          "blur; this file gives blur_px")
    out: dict[str, float] = {}
    for line, row in enumerate(rows, start=2):
        if not row or not "".join(row).strip():
            continue
        if len(row) != len(header):
            raise InputFileError(f"{path}:{line}: expected {len(header)} values "
                                 f"({','.join(header)}), got {len(row)}")
        ref = row[0].strip()
        image = truth.resolve(ref) or truth.resolve(Path(ref).stem)
        if image is None:
            raise InputFileError(f"{path}:{line}: image {ref!r} is not in {truth.source}")
        if image in out:
            raise InputFileError(f"{path}:{line}: image {ref!r} given twice")
        values = []
        for name, cell in zip(header[1:], row[1:], strict=True):
            try:
                v = float(cell)
            except ValueError:
                v = math.nan
            if not (math.isfinite(v) and v >= 0) or (name == "height_m" and v == 0):
                raise InputFileError(f"{path}:{line}: {name}: expected a finite number "
                                     f"{'> 0' if name == 'height_m' else '>= 0'}, "
                                     f"got {cell!r}")
            values.append(v)
        out[image] = values[0] if speed is None else speed.blur_px(values[0], values[1])
    missing = [k for k in truth.images if k not in out]
    if missing:
        raise InputFileError(f"{path}: no row for {len(missing)} of the {len(truth.images)} "
                             f"images of {truth.source} (first: {', '.join(missing[:3])}); "
                             "every image needs its blur")
    return out
