"""Re-tasking end to end, on loopback (the router's access control on pdcov/<id>/retask:
tests/system/test_security_zenoh.py; the signed requests' refusals:
tests/system/test_retask_signed_e2e.py):
``pdcov watch --refly --operator-key`` sends a signed re-fly of the live grid's gaps,
over real Zenoh, to the daemon flying the real ArduCopter (../shared/ardupilot-sitl) in
AUTO, which accepts it with MISSION_ACK; read back with MISSION_REQUEST_LIST it is the new
mission, and the flight mode is still the pilot's AUTO."""

from __future__ import annotations

import subprocess
import sys

import pytest

from pdcov.cli import main as pdcov_main
from pdcov.core.mission import MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT, MissionItem
from pdcov.planning.plan_files import read_mission
from pdcov.telemetry.link_params import wait_autopilot
from pdcov.telemetry.upload import mavlink2_connection
from tests.support.ardupilot_sitl import (
    FLIGHT_MISSION,
    MOUNT_SERVO_PARM,
    ardupilot_sitl,
    fly_mission,
    requires_ardupilot_sitl,
)
from tests.support.retask_keys import write_key, write_pub
from tests.support.serve_harness import (
    Subscriber,
    free_port,
    process,
    router,
    serve_args,
    serve_config,
    stop,
)

ITEMS = (MissionItem(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT, lat_deg=-35.3631,
                     lon_deg=149.1652, z_m=10.0),)


# --- mid-flight, on the real ArduCopter -------------------------------------------------

SPEEDUP = 10
ALTITUDE_M = 10.0
ARDU_MISSION = FLIGHT_MISSION


def read_back(conn, target: tuple[int, int], timeout_s: float = 10.0) -> list:
    """The autopilot's mission, MISSION_REQUEST_LIST then one MISSION_REQUEST_INT per item:
    its MISSION_ITEM_INT messages in order (seq 0: ArduPilot's home)."""
    conn.mav.mission_request_list_send(*target, 0)
    count = conn.recv_match(type="MISSION_COUNT", blocking=True, timeout=timeout_s)
    assert count is not None, "no MISSION_COUNT"
    items = []
    for seq in range(count.count):
        for _ in range(3):
            conn.mav.mission_request_int_send(*target, seq, 0)
            item = conn.recv_match(type="MISSION_ITEM_INT", blocking=True, timeout=2.0)
            if item is not None and item.seq == seq:
                items.append(item)
                break
        else:
            pytest.fail(f"item {seq} not read back")
    conn.mav.mission_ack_send(*target, 0, 0)
    return items


def mode_of(conn, target: tuple[int, int]) -> int:
    while True:
        hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=5.0)
        assert hb is not None, "no HEARTBEAT"
        if hb.get_srcSystem() == target[0] and hb.get_srcComponent() == target[1]:
            return hb.custom_mode


@requires_ardupilot_sitl
def test_refly_uploaded_mid_flight_to_real_arducopter(tmp_path) -> None:
    zport = free_port()
    write_pub(tmp_path)
    config = serve_config(ARDU_MISSION, tmp_path / "mission.yaml", zenoh_port=zport,
                          state_dir=tmp_path / "state", retask=True,
                          retask_operator_keys=["operator.pub"])
    assert pdcov_main(["plan", "--config", str(config), "--pattern", "lawnmower",
                       "--altitude-m", str(ALTITUDE_M), "--out", str(tmp_path / "plan"),
                       "--no-figures"]) == 0
    plan = tmp_path / "plan" / "plan.plan"
    original = read_mission(plan).items
    zrouter = router(zport)
    try:
        with ardupilot_sitl(tmp_path / "sitl", [MOUNT_SERVO_PARM], speedup=SPEEDUP) as sitl:
            gcs = mavlink2_connection(sitl.serial_url(0), 255, 190)
            try:
                target = wait_autopilot(gcs, 30.0)
                with process(serve_args(config, "--connect", sitl.serial_url(2)),
                             tmp_path / "serve.log") as daemon:
                    sub = Subscriber(zport, "ardu1")
                    try:
                        sub.wait(lambda s: s["link"]["state"] == "connected", 60.0,
                                 "the daemon connected")
                        assert pdcov_main(["upload", "--connect", sitl.serial_url(1),
                                           str(plan)]) == 0
                        # In AUTO, a few legs into the lawnmower: mid-flight, gaps left.
                        fly_mission(gcs, target, 4, altitude_m=ALTITUDE_M, timeout_s=120.0)
                        assert mode_of(gcs, target) == 3  # AUTO, set by the "pilot"
                        sub.wait(lambda s: s["frames"]["used"] > 0, 30.0, "frames")
                        watch = subprocess.run(
                            [sys.executable, "-m", "pdcov.cli", "watch", "--config",
                             str(config), "--vehicle", "ardu1", "--mode", "client",
                             "--zenoh-connect", f"tcp/127.0.0.1:{zport}", "--refly", "ardu1",
                             "--target-pd", "0.8", "--yes", "--wait-s", "10",
                             "--operator-key", str(write_key(tmp_path / "ground"))],
                            capture_output=True, text=True, timeout=120)
                        assert watch.returncode == 0, watch.stdout + watch.stderr
                        assert "the autopilot accepted" in watch.stdout, watch.stdout
                        mode_after = mode_of(gcs, target)
                        back = read_back(gcs, target)
                        st = sub.wait(lambda s: (s.get("retask") or {}).get("last")
                                      is not None, 30.0, "the status's retask")
                        assert stop(daemon) == 0
                    finally:
                        sub.close()
            finally:
                gcs.close()
    finally:
        zrouter.close()
    assert mode_after == 3, "the flight mode changed"
    last = st["retask"]["last"]
    assert last["accepted"] and last["result"] == "MAV_MISSION_ACCEPTED"
    assert f"mission {last['plan_hash']}" in watch.stdout
    # The new mission, item for item: as many as the daemon uploaded, not the old one.
    assert len(back) == last["items"]
    waypoints = [(m.x, m.y) for m in back[1:] if m.command == 16]
    old = [(round(i.lat_deg * 1e7), round(i.lon_deg * 1e7)) for i in original
           if i.command == 16]
    assert waypoints and waypoints != old
    assert "re-tasking: mission" in (tmp_path / "serve.log").read_text()
