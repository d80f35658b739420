"""Where the simulated detector's boxes go: ``pdcov/<vehicle_id>/frames`` over Zenoh (the
frames payload version 2, ``bus/frames.py``, one message per camera frame, as an onboard
detector publishes them) and ``detections.csv`` in the output folder.

The session is found as the daemon finds its bus: the mission's ``bus`` section
(``bus/session.py``), with ``--zenoh-connect`` endpoints in place of its connect list.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import IO

from pdcov.bus.frames import MAX_BOXES_PER_FRAME, encode_frames_v2
from pdcov.bus.keys import VehicleKeys
from pdcov.bus.session import BusConfig, open_session
from pdcov.core.detections import FrameBoxes

from .detector import SimulatedDetection

DETECTIONS_CSV_COLUMNS = ("t_boot_s", "person_id", "class", "confidence", "left_px",
                          "top_px", "width_px", "height_px")


class DetectionOutput:
    """Publishes each frame's boxes and writes them to ``csv_path``; ``close`` ends both.
    A frame keeps at most MAX_BOXES_PER_FRAME boxes (people first), as the daemon takes
    no more; ``dropped`` counts the rest."""

    def __init__(self, bus: BusConfig, vehicle_id: str, csv_path: Path) -> None:
        self.key = VehicleKeys(vehicle_id).frames
        self._csv: IO[str] = open(csv_path, "w", newline="")
        self._rows = csv.writer(self._csv, lineterminator="\n")
        self._rows.writerow(DETECTIONS_CSV_COLUMNS)
        try:
            self.session = open_session(bus)
        except BaseException:
            self._csv.close()
            raise
        self.publisher = self.session.declare_publisher(self.key)
        self.frames = 0
        self.boxes = 0
        self.dropped = 0

    def frame(self, t_boot_s: float, detections: list[SimulatedDetection]) -> None:
        """One camera frame at ``t_boot_s`` (autopilot boot clock, s) and its boxes."""
        kept = detections[:MAX_BOXES_PER_FRAME]
        self.dropped += len(detections) - len(kept)
        self.publisher.put(encode_frames_v2([FrameBoxes(t_boot_s, tuple(d.box for d in kept))]))
        for d in kept:
            b = d.box
            self._rows.writerow([f"{t_boot_s:.3f}", d.person_id, b.class_name,
                                 f"{b.confidence:.4f}", *(f"{v:.3f}" for v in b.box_px)])
        self.frames += 1
        self.boxes += len(kept)

    def close(self) -> None:
        try:
            self.publisher.undeclare()
            self.session.close()
        finally:
            self._csv.close()
