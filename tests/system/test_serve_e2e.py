"""``pdcov serve`` end to end, loopback only: a MAVLink source (pdcov-sitl replay of a real
ArduPilot log or of generated tlogs), the daemon, an in-process Zenoh router and subscriber.
The subscriber's grid (tiles applied, and the snapshot) must equal the daemon's checkpoint
and ``pdcov evaluate`` of the same telemetry, cell for cell."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from pdcov.bus.footprint import decode_footprint
from pdcov.cli import main as pdcov_main
from tests.support.checkpoint_files import read_checkpoint
from tests.support.cmac_mission import CMAC
from tests.support.serve_harness import (
    REAL,
    Subscriber,
    free_port,
    process,
    router,
    serve_args,
    serve_config,
    stop,
)

TLOG = REAL / "ardupilot_sitl_servo_gimbal.tlog"


def evaluate_offline(config, tlog, out) -> dict:
    assert pdcov_main(["evaluate", "--config", str(config), "--log", str(tlog), "--out",
                       str(out), "--no-progress"]) == 0
    with np.load(out / "grid.npz") as z:
        return {k: z[k] for k in z.files}


def assert_same_grid(state, ref: dict, what: str) -> None:
    for key in ("log_miss_d", "log_miss_fa", "n_obs"):
        np.testing.assert_array_equal(getattr(state, key), ref[key], err_msg=f"{what}: {key}")


@pytest.mark.skipif(not TLOG.exists(), reason=f"{TLOG} not present")
def test_real_flight_replay_equals_offline(tmp_path):
    """ardupilot_sitl_servo_gimbal.tlog replayed into the daemon gives the grid
    ``pdcov evaluate`` gives for that log; the subscriber rebuilds it exactly."""
    zport, mport = free_port(), free_port()
    cfg = serve_config(CMAC, tmp_path / "m.yaml", zenoh_port=zport, state_dir=tmp_path / "st")
    ref = evaluate_offline(cfg, TLOG, tmp_path / "offline")
    r = router(zport)
    sub = Subscriber(zport, "uav1")
    try:
        with process(serve_args(cfg, "--connect", f"tcp:127.0.0.1:{mport}"),
                     tmp_path / "serve.log") as daemon, \
             process([sys.executable, "-m", "pdcov_sitl.cli", "replay", str(TLOG),
                      "--connect", f"tcp:127.0.0.1:{mport}", "--speed", "0"],
                     tmp_path / "replay.log") as replay:
            sub.wait(lambda s: s["frames"]["grid"] >= int(ref["frames"]), 150,
                     f"{int(ref['frames'])} frames")
            replay.wait(timeout=60)
            st = sub.wait(lambda s: s["tiles_seq"] == sub.last_seq, 30, "the last tiles")
            fp = decode_footprint(sub.footprint())
            snap = sub.snapshot()
            assert stop(daemon) == 0
        log_text = (tmp_path / "serve.log").read_text()
        assert st["frames"]["grid"] == int(ref["frames"]), log_text[-2000:]
        assert st["gimbal"]["interpretation"] == "flags"
        assert st["grid"]["origin"]["ground_alt_msl_m"] == pytest.approx(584.08)
        assert st["link"]["system_id"] == 1 and st["pose"] is not None
        assert fp["properties"]["vehicle_id"] == "uav1"
        assert not sub.errors
        assert_same_grid(sub.grid, ref, "tiles")
        assert_same_grid(snap, ref, "snapshot")
        z = read_checkpoint(tmp_path / "st" / "checkpoint")
        assert_same_grid(snap, z, "checkpoint")
        meta = z["meta"]
        assert meta["mission_hash"] and meta["last_frame_t_s"] > 100
        # The daemon's own recording evaluates to the same grid.
        rec = sorted((tmp_path / "st" / "recordings").glob("*.tlog"))
        assert rec, log_text[-2000:]
        again = evaluate_offline(cfg, rec[0], tmp_path / "again")
        assert_same_grid(sub.grid, again, "recording")
        assert "<6>" in log_text and "Traceback" not in log_text
    finally:
        sub.close()
        r.close()
