"""detections.json of ``pdcov evaluate`` (docs/outputs.md): the detector boxes a daemon
recorded with its frames, geolocated and grouped by the daemon's own rule
(detection/candidates.py) with the poses the grid took, in the daemon's order, so that the
document is the one the daemon answered on the bus (bus/detections.py)."""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from pdcov.atomic import write_text_atomic
from pdcov.bus.detections import detections_document
from pdcov.config import Mission
from pdcov.core.camera import CameraModel
from pdcov.core.detections import Box, Detection
from pdcov.core.geodesy import Origin
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose
from pdcov.detection.candidates import DetectionTracker

__all__ = ["DETECTIONS_FILE", "flight_detections", "write_detections"]

DETECTIONS_FILE = "detections.json"


def flight_detections(mission: Mission, grid: CoverageGrid, origin: Origin,
                      poses: Iterable[CameraPose],
                      frame_boxes: Mapping[float, tuple[float, tuple[Box, ...]]],
                      cameras: Sequence[CameraModel | None] = ()) -> dict[str, Any]:
    """The detections document of a flight: every frame of ``poses`` (those the grid took,
    in time order, with ``cameras`` their zoomed cameras, if any) with boxes in
    ``frame_boxes`` ({t_s: (t_boot_s, boxes)}), and every candidate with ``grid``'s looks,
    P_D and P_FA at its cell."""
    tracker = DetectionTracker.for_mission(mission)
    detections: list[Detection] = []
    for i, pose in enumerate(poses):
        held = frame_boxes.get(pose.t_s)
        if held is not None:
            detections += tracker.frame(pose, *held, camera=cameras[i] if cameras else None)
    return detections_document(detections, tracker.candidates(grid), origin,
                               mission.vehicle_id,
                               lambda cid: f"{tracker.uid_prefix}{cid}")  # an evicted one's


def write_detections(out_dir: Path, doc: Mapping[str, Any]) -> Path:
    """Write ``doc`` as ``out_dir``/detections.json (atomically); its path."""
    path = out_dir / DETECTIONS_FILE
    write_text_atomic(path, json.dumps(doc, indent=1, allow_nan=False) + "\n")
    return path
