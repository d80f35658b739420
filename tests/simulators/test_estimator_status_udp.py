"""A PX4 GPS glitch from the simulator over UDP: the daemon's grid equals evaluate's of its
recording."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("MAVLINK20", "1")


from pdcov.telemetry.estimator import GPS_GLITCHING
from pdcov.telemetry.link_protocol import ESTIMATOR_STATUS
from tests.support.harness import small_mission
from tests.support.serve_harness import (
    Subscriber,
    free_port,
    process,
    router,
    serve_args,
    small_plan,
    stop,
)
from tests.support.serve_harness import serve_config as write_config


def test_px4_glitch_over_udp_live_equals_offline(tmp_path: Path) -> None:
    """A PX4-like lawnmower whose GPS glitches 20 m for 4 s (gps_glitch=30+4:20): the daemon
    asks ESTIMATOR_STATUS at 5 Hz, skips the frames the estimator flags (and the frames
    across the two jumps as 'position jump'), counts them in its status, and its grid equals
    ``pdcov evaluate`` of its recording and of the simulator's own tlog, cell for cell."""
    doc = small_mission(vehicle_id="est1", coverage={"min_revisit_s": 1.0},
                        mount={"type": "fixed", "roll_deg": 0, "pitch_deg": -90, "yaw_deg": 0})
    plan = small_plan(tmp_path, doc)
    zport, mport = free_port(), free_port()
    cfg = write_config(doc, tmp_path / "serve.yaml", zenoh_port=zport,
                       state_dir=tmp_path / "st")
    fly = [sys.executable, "-m", "pdcov_sitl.cli", "fly", "--config", str(cfg), "--plan",
           str(plan), "--out", str(tmp_path / "fly"), "--connect",
           f"udpout:127.0.0.1:{mport}", "--speed", "6", "--autopilot", "px4", "--gimbal",
           "fixed", "--faults", "gps_glitch=30+4:20"]
    r = router(zport)
    sub = None
    try:
        sub = Subscriber(zport, "est1")
        with process(serve_args(cfg, "--connect", f"udpin:127.0.0.1:{mport}"),
                     tmp_path / "serve.log") as daemon:
            sub.wait(lambda s: True, 60, "the daemon's first status")
            with process(fly, tmp_path / "fly.log") as sim:
                assert sim.wait(timeout=300) == 0, (tmp_path / "fly.log").read_text()[-2000:]
            seen: list = [None, 0]

            def settled(st: dict) -> bool:  # the same telemetry time and frames 6 times
                key = (st["t_s"], st["frames"]["grid"], st["frames"]["pending"])
                seen[:] = [key, seen[1] + 1] if key == seen[0] else [key, 0]
                return seen[1] >= 5 and st["tiles_seq"] == sub.last_seq

            sub.wait(settled, 90, "the last telemetry and tiles")
            time.sleep(0.5)
            st, snap = sub.status, sub.snapshot()
            assert stop(daemon) == 0
    finally:
        if sub is not None:
            sub.close()
        r.close()

    rate = doc["camera"]["frame_rate_hz"]
    skipped = st["frames"]["skipped"]
    # 4 s of glitch, flagged from the first report after 30 s (5 Hz) to the first after 34 s;
    # the frames across the jump at 30 s come before the flag.
    assert 3.0 * rate <= skipped.get(GPS_GLITCHING, 0) <= 4.5 * rate, skipped
    # Both jumps are seen; a frame lies strictly between the two samples of a jump only
    # for some phases of the position stream (set by when the link's interval request
    # reached the simulator), so 'position jump' frames may be 0.
    assert st["faults"]["position_jumps"] == 2, st["faults"]
    assert "frames_without_estimator_status" not in st["faults"] or \
        st["faults"]["frames_without_estimator_status"] < 2 * rate, st["faults"]
    assert ESTIMATOR_STATUS in st["link"]["intervals"].get("acked", []), st["link"]
    recording = sorted((tmp_path / "st" / "recordings").glob("*.tlog"))
    assert len(recording) == 1
    for tlog, name in ((recording[0], "rec"), (tmp_path / "fly" / "flight.tlog", "sim")):
        res = subprocess.run([sys.executable, "-m", "pdcov.cli", "evaluate", "--config",
                              str(cfg), "--log", str(tlog), "--out", str(tmp_path / name),
                              "--no-progress"], capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr[-2000:]
        assert f"{GPS_GLITCHING} {skipped[GPS_GLITCHING]}" in res.stdout, res.stdout
        with np.load(tmp_path / name / "grid.npz") as z:
            for key in ("log_miss_d", "log_miss_fa", "n_obs"):
                np.testing.assert_array_equal(getattr(snap, key), z[key],
                                              err_msg=f"{name}: {key}")
            assert int(z["frames"]) == st["frames"]["grid"] > 100
