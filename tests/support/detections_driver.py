"""The daemon's decisions driven over a known flight with a detector in memory, for the tests of
the published detections and candidates live and offline."""

from __future__ import annotations

from pathlib import Path

from pdcov.bus.detections import decode_detections
from pdcov.service.core import ServiceCore
from pdcov.service.recorder import TlogRecorder
from pdcov.service.settings import load_serve_config
from pdcov.telemetry.tlog import mavlink


class Driver:
    """The shell's part, in memory: what the core says to record is recorded; detections
    messages are kept; time steps by hand."""

    def __init__(self, cfg_path: Path, rec_dir: Path) -> None:
        self.core = ServiceCore(load_serve_config(cfg_path),
                                load_serve_config(cfg_path).mission.new_mission_grid(), 0.0,
                                mission_hash="test")
        self.recorder = TlogRecorder(rec_dir, 1 << 22, 1 << 30)
        self.parser = mavlink.MAVLink(None)
        self.now_s = 0.0
        self.published: list[dict] = []

    def _do(self) -> None:
        a = self.core.actions()
        for data in a.record:
            self.recorder.write(data, 1.7e9 + self.now_s)
        self.published += [decode_detections(p, vehicle_id="uav7") for p in a.detections]

    def link(self, data: bytes) -> None:
        self.core.receive_mavlink(self.parser.parse_buffer(data) or [], self.now_s)
        self.core.process()
        self._do()

    def frames(self, payload: bytes) -> None:
        self.core.receive_frames(payload)
        self._do()

    def tick(self, dt_s: float) -> None:
        self.now_s += dt_s
        self.core.tick(self.now_s, 0.0)
        self._do()
