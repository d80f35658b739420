"""Candidates survive a restart of ``pdcov serve`` (issue 35, point 1), with real processes:
a daemon fed a hover over UDP and a detector's frames with boxes on Zenoh publishes
detections; stopped with SIGTERM and started again on its state directory it answers the
candidates query with the same candidates (ids, positions, every field); killed with
SIGKILL after a detections publish, every candidate it published is there after the
restart (the journal), and new ones continue the ids."""

from __future__ import annotations

import signal
import socket
import threading
import time
from pathlib import Path

from pdcov.bus.detections import decode_detections
from pdcov.bus.frames import encode_frames_v2
from pdcov.bus.keys import VehicleKeys
from pdcov.bus.session import BusConfig, open_session
from pdcov.core.detections import Box, FrameBoxes
from tests.support import serve_harness
from tests.support.harness import small_mission
from tests.support.link_feed import FIXED, Hover, pack
from tests.support.serve_harness import free_port, process, router, serve_args, serve_config, stop

KEYS = VehicleKeys("uav7")
FRAMES = [FrameBoxes(1.2 + 0.2 * k, (
    Box("person", 0.8, 310.0 + k % 3, 200.0, 18.0, 40.0),  # near the centre
    Box("person", 0.6, 10.0, 300.0, 12.0, 30.0),  # at the left edge
    *((Box("car", 0.7, 500.0, 100.0, 60.0, 30.0),) if k % 2 else ())))
    for k in range(16)]  # 1.2 .. 4.2 s of the hover's 1.0 .. 4.9 s
BOXES = sum(len(f.boxes) for f in FRAMES)


class Ground:
    """A client session: the detections published, the candidates query, the frames put."""

    def __init__(self, zport: int) -> None:
        self.session = open_session(BusConfig(mode="client",
                                              connect=(f"tcp/127.0.0.1:{zport}",),
                                              multicast_scouting=False))
        self.lock = threading.Lock()
        self.detections: list[dict] = []
        self.sub = self.session.declare_subscriber(KEYS.detections, self._on)
        self.frames = self.session.declare_publisher(KEYS.frames)

    def _on(self, sample) -> None:
        doc = decode_detections(sample.payload.to_bytes(), vehicle_id="uav7")
        with self.lock:
            self.detections.append(doc)

    def published(self) -> tuple[int, set[int]]:
        """Detections published so far, and the candidate ids they carried."""
        with self.lock:
            docs = list(self.detections)
        return (sum(len(d["detections"]) for d in docs),
                {c["id"] for d in docs for c in d["candidates"]})

    def candidates(self) -> list[dict]:
        return serve_harness.candidates_query(self.session, KEYS)

    def wait(self, predicate, timeout_s: float, what: str) -> None:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if predicate():
                return
            time.sleep(0.05)
        raise AssertionError(f"timed out waiting for {what}: {self.published()}")

    def close(self) -> None:
        self.sub.undeclare()
        self.frames.undeclare()
        self.session.close()


def fly(mport: int, ground: Ground, frames: list[FrameBoxes], seconds: float = 4.0) -> None:
    """The hover's datagrams to the daemon's UDP port, then the frames on Zenoh. (A
    restarted daemon continues the autopilot's clock: the hover's times, from 1 s again,
    are a reboot, which its frames must come after.)"""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i, msg in enumerate(Hover(seconds=seconds).messages()):
            s.sendto(pack(msg, seq=i), ("127.0.0.1", mport))
            if i % 50 == 49:
                time.sleep(0.01)  # a small socket buffer on a loaded machine
    time.sleep(0.5)
    ground.frames.put(encode_frames_v2(frames))


def test_candidates_survive_sigterm_and_sigkill(tmp_path: Path) -> None:
    zport, mport = free_port(), free_port(socket.SOCK_DGRAM)
    state = tmp_path / "state"
    cfg = serve_config(small_mission(vehicle_id="uav7", mount=FIXED,
                                     coverage={"min_revisit_s": 1.0}),
                       tmp_path / "m.yaml", zenoh_port=zport, state_dir=state,
                       frame_source="zenoh", reorder_s=0.0, record=False,
                       checkpoint_period_s=600.0)
    args = serve_args(cfg, "--connect", f"udpin:127.0.0.1:{mport}")
    r = router(zport)
    ground = Ground(zport)
    try:
        # 1. Published, then SIGTERM: the final checkpoint holds every candidate.
        with process(args, tmp_path / "serve1.log") as daemon:
            ground.candidates()  # the daemon is up and on the bus
            fly(mport, ground, FRAMES)
            ground.wait(lambda: ground.published()[0] == BOXES, 60, "every detection")
            before = ground.candidates()
            assert stop(daemon) == 0
        assert [c["class"] for c in before] == ["person", "person", "car"]
        assert ground.published()[1] == {0, 1, 2}
        with process(args, tmp_path / "serve2.log") as daemon:
            after = ground.candidates()
            # The resumed grid is the one they were seen in: every field the same.
            assert after == before
            # 2. New candidates continue the ids; kill -9 after their publish.
            n = len(ground.detections)
            fly(mport, ground, [FrameBoxes(5.0, (Box("person", 0.9, 600.0, 440.0, 12.0,
                                                      30.0),))], seconds=5.5)
            ground.wait(lambda: len(ground.detections) > n, 60, "the new detection")
            daemon.send_signal(signal.SIGKILL)
            daemon.wait(timeout=20)
        published = ground.published()[1]
        assert published == {0, 1, 2, 3}
        with process(args, tmp_path / "serve3.log") as daemon:
            restored = {c["id"]: c for c in ground.candidates()}
            assert set(restored) == published
            for c in before:  # where they were (the grid since may differ: looks)
                assert (restored[c["id"]]["x_m"], restored[c["id"]]["y_m"]) == (
                    c["x_m"], c["y_m"])
            assert stop(daemon) == 0
        log = (tmp_path / "serve3.log").read_text()
        assert "journal lines" in log, log[-2000:]
    finally:
        ground.close()
        r.close()
