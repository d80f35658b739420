"""``pdcov serve`` live on the real ArduCopter 4.7 firmware (../shared/ardupilot-sitl), loopback
only: the daemon connects over TCP (SERIAL2), asks for its streams, reads the servo mount's
parameters (``attitude_frame: auto`` must choose ``body``); a plan made by ``pdcov plan`` is
uploaded with ``pdcov upload`` (SERIAL1) and flown (GUIDED take-off, then AUTO, from a
ground-station link on SERIAL0); at the end the daemon's snapshot equals ``pdcov evaluate``
of the tlog the daemon recorded, cell for cell."""

from __future__ import annotations

import time

import numpy as np

from pdcov.cli import main as pdcov_main
from pdcov.planning.plan_files import read_mission
from pdcov.telemetry.link_params import wait_autopilot
from pdcov.telemetry.link_protocol import (
    ATTITUDE,
    GIMBAL_DEVICE_ATTITUDE_STATUS,
    GLOBAL_POSITION_INT,
)
from pdcov.telemetry.upload import mavlink2_connection
from tests.support.ardupilot_sitl import (
    FLIGHT_MISSION,
    MOUNT_SERVO_PARM,
    ardupilot_sitl,
    fly_mission,
    requires_ardupilot_sitl,
)
from tests.support.serve_harness import (
    Subscriber,
    free_port,
    process,
    router,
    serve_args,
    serve_config,
    stop,
)

SPEEDUP = 10  # autopilot seconds per wall second; the daemon works in the autopilot's clock
ALTITUDE_M = 10.0
MISSION = FLIGHT_MISSION


@requires_ardupilot_sitl
def test_daemon_flies_with_real_arducopter_and_equals_offline(tmp_path) -> None:
    t_start = time.monotonic()
    zport = free_port()
    state = tmp_path / "state"
    config = serve_config(MISSION, tmp_path / "mission.yaml", zenoh_port=zport, state_dir=state)
    assert pdcov_main(["plan", "--config", str(config), "--pattern", "lawnmower",
                       "--altitude-m", str(ALTITUDE_M), "--out", str(tmp_path / "plan"),
                       "--no-figures"]) == 0
    plan = tmp_path / "plan" / "plan.plan"
    # Mission items after ArduPilot's home (seq 0): the last is RTL; its leg before is last.
    last_waypoint_seq = len(read_mission(plan).items) - 1

    zrouter = router(zport)
    try:
        with ardupilot_sitl(tmp_path / "sitl", [MOUNT_SERVO_PARM], speedup=SPEEDUP) as sitl:
            gcs = mavlink2_connection(sitl.serial_url(0), 255, 190)  # boots the firmware
            try:
                target = wait_autopilot(gcs, 30.0)
                with process(serve_args(config, "--connect", sitl.serial_url(2)),
                             tmp_path / "serve.log") as daemon:
                    sub = Subscriber(zport, MISSION["vehicle_id"])
                    try:
                        st = sub.wait(lambda s: s["gimbal"]["interpretation"] == "body"
                                      and s["link"]["state"] == "connected", 60.0,
                                      "the daemon to read the mount parameters")
                        assert pdcov_main(["upload", "--connect", sitl.serial_url(1),
                                           str(plan)]) == 0
                        fly_mission(gcs, target, last_waypoint_seq, altitude_m=ALTITUDE_M,
                                    timeout_s=120.0)
                        flown = sub.wait(lambda s: s["frames"]["used"] > 0, 30.0, "frames")
                        # Telemetry ends with the autopilot; once the daemon has seen the
                        # link go and its frame count holds still, its snapshot is final (a
                        # frame after the last sample stays pending: nothing to interpolate).
                        sitl.process.kill()
                        lost = sub.wait(lambda s: s["link"]["state"] != "connected", 30.0,
                                        "the daemon to see the link end")
                        settled = sub.wait(lambda s: s["seq"] >= lost["seq"] + 3, 10.0,
                                           "three more statuses")
                        assert settled["frames"]["used"] == lost["frames"]["used"]
                        snapshot = sub.snapshot()
                        assert stop(daemon) == 0
                    finally:
                        sub.close()
            finally:
                gcs.close()
    finally:
        zrouter.close()

    link = st["link"]
    acked = {int(k) for k in link["intervals"]["acked"]}
    assert {ATTITUDE, GLOBAL_POSITION_INT, GIMBAL_DEVICE_ATTITUDE_STATUS} <= acked, link
    assert link["params"]["MNT1_TYPE"] == 1, link["params"]
    assert "MNT1_TYPE" in st["gimbal"]["describe"], st["gimbal"]
    assert flown["frames"]["used"] > 0
    assert settled["proportion_at_or_above"]["0.8"] > 0.5, settled

    recordings = sorted((state / "recordings").glob("*.tlog"))
    assert recordings, "the daemon recorded no tlog"
    out = tmp_path / "offline"
    assert pdcov_main(["evaluate", "--config", str(config), "--log", str(recordings[0]),
                       "--out", str(out), "--no-progress"]) == 0
    with np.load(out / "grid.npz") as ref:
        for key in ("log_miss_d", "log_miss_fa", "n_obs"):
            np.testing.assert_array_equal(getattr(snapshot, key), ref[key], err_msg=key)
    assert time.monotonic() - t_start < 180.0
