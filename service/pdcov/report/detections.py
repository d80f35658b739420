"""detections.json of ``pdcov evaluate`` (docs/outputs.md): the detector boxes a daemon
recorded with its frames, geolocated and grouped by the daemon's own rule
(detection/candidates.py) with the poses the grid took, in the daemon's order, so that the
document is the one the daemon answered on the bus (bus/detections.py)."""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.atomic import write_text_atomic
from pdcov.bus.detections import detections_document
from pdcov.config.mission import Mission
from pdcov.core.camera import CameraModel
from pdcov.core.detections import Box, Detection
from pdcov.core.geodesy import Origin
from pdcov.core.geolocate import PositionAccuracy
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose
from pdcov.core.utc_clock import UtcClock
from pdcov.detection.candidates import DetectionTracker
from pdcov.errors import InputFileError

__all__ = ["DETECTIONS_FILE", "flight_detections", "log_epoch", "merged_detections",
           "write_detections"]

DETECTIONS_FILE = "detections.json"


def flight_detections(mission: Mission, grid: CoverageGrid, origin: Origin,
                      poses: Sequence[CameraPose],
                      frame_boxes: Mapping[float, tuple[float, tuple[Box, ...]]],
                      cameras: Sequence[CameraModel | None] = (),
                      accuracies: Sequence[PositionAccuracy | None] = (), *,
                      uid_prefix: str, poa: np.ndarray | None = None,
                      utc: UtcClock | None = None) -> dict[str, Any]:
    """The detections document of a flight: every frame of ``poses`` (those the grid took,
    in time order, with ``cameras`` their zoomed cameras and ``accuracies`` the position
    accuracy the autopilot reported, if any) with boxes in ``frame_boxes``
    ({t_s: (t_boot_s, boxes)}), and every candidate with ``grid``'s (the published one)
    P_D and P_FA at its cell. The tracker sees each frame's looks as the daemon's did: a
    fresh grid of the mission's first camera takes the frames one by one. ``uid_prefix``: the
    candidates' (ids.candidate_uid_prefix, with the log's epoch, ``log_epoch``); ``poa``: a
    probability of area per cell for the candidates' prior; ``utc``: the log's real-time
    clock, which stamps each frame's detections with the UTC of its pose's time (none: no
    UTC)."""
    tracker = DetectionTracker.for_mission(mission, uid_prefix, poa)
    own = mission.new_grid(mission.first_camera)
    detections: list[Detection] = []
    for i, pose in enumerate(poses):
        camera = cameras[i] if cameras else None
        own.update_with(pose, camera)
        t_boot_s, boxes = frame_boxes.get(pose.t_s, (pose.t_s, ()))
        detections += tracker.frame(pose, t_boot_s, boxes, camera=camera,
                                    accuracy=accuracies[i] if accuracies else None, grid=own,
                                    unix_s=math.nan if utc is None else utc.unix_s(pose.t_s))
    return detections_document(detections, tracker.candidates(grid), origin,
                               mission.vehicle_id, tracker.uid_of)


def merged_detections(docs: Sequence[Mapping[str, Any]], grid: CoverageGrid
                      ) -> dict[str, Any]:
    """The detections documents of several logs of one vehicle (``flight_detections``, in
    log order) as one: every detection and candidate, each log's candidate ids shifted past
    the previous logs' (ids stay unique; the uids, with each log's epoch, are kept), and
    each candidate's P_D and P_FA those of ``grid`` (the merged one) at the cell of its
    position (x_m, y_m; 0 outside the grid), as ``DetectionTracker.candidates`` gives them."""
    geo = grid.geometry
    detections: list[dict[str, Any]] = []
    candidates: list[dict[str, Any]] = []
    offset = 0
    for doc in docs:
        ids = [c["id"] for c in doc["candidates"]] + [d["candidate"] for d in
                                                       doc["detections"]]
        detections += [{**d, "candidate": d["candidate"] + offset} for d in doc["detections"]]
        for c in doc["candidates"]:
            row, col = (int(v) for v in geo.cell_of(c["x_m"], c["y_m"]))
            inside = 0 <= row < geo.n_rows and 0 <= col < geo.n_cols
            pd, pfa = ((float(-np.expm1(float(grid.log_miss_d[row, col]))),
                        float(-np.expm1(float(grid.log_miss_fa[row, col])))) if inside
                       else (0.0, 0.0))
            candidates.append({**c, "id": c["id"] + offset, "pd": min(max(pd, 0.0), 1.0),
                               "pfa": min(max(pfa, 0.0), 1.0)})
        offset += max(ids, default=-1) + 1
    return {**docs[0], "detections": detections, "candidates": candidates}


def log_epoch(path: Path) -> str:
    """The epoch of a flight log's candidate uids: the first 6 hex digits of the SHA-256 of
    its bytes (the same log, the same uids; read in 1 MiB blocks)."""
    h = hashlib.sha256()
    try:
        with path.open("rb") as f:
            while block := f.read(1 << 20):
                h.update(block)
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read ({exc.strerror or exc})") from None
    return h.hexdigest()[:6]


def write_detections(out_dir: Path, doc: Mapping[str, Any]) -> Path:
    """Write ``doc`` as ``out_dir``/detections.json (atomically); its path."""
    path = out_dir / DETECTIONS_FILE
    write_text_atomic(path, json.dumps(doc, indent=1, allow_nan=False) + "\n")
    return path
