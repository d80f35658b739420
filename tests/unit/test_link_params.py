"""Reading the mount parameters from a live autopilot over a real UDP socket on 127.0.0.1.

The autopilot is a vehicle-side peer written here with pymavlink: it answers the ground
station's HEARTBEAT as an ArduPilot quadrotor and each PARAM_REQUEST_READ (by name) with a
PARAM_VALUE from its parameter table, or with nothing for a name it does not have (as
ArduPilot does). It can drop the first request of each name, and put a ground station's
HEARTBEAT, other traffic and another system's PARAM_VALUE on the link before its own.
"""

from __future__ import annotations

import pytest

from pdcov.cli import main
from pdcov.core.mount import GimbalMount
from pdcov.errors import TelemetryError
from pdcov.telemetry.gimbal import resolve_interpretation
from pdcov.telemetry.link_params import (
    legacy_mount_param_names,
    mount_param_names,
    read_mount_params,
    read_params,
    wait_autopilot,
)
from pdcov.telemetry.upload import mavlink2_connection
from tests.support.evaluate_inputs import mission_doc, write_config
from tests.support.link_params_autopilot import SYSID, gimbal_config

SERVO_PARAMS = {"MNT1_TYPE": 1, "MNT1_ROLL_MIN": -30, "MNT1_ROLL_MAX": 30,
                "MNT1_PITCH_MIN": -90, "MNT1_PITCH_MAX": 20, "MNT1_YAW_MIN": -180,
                "MNT1_YAW_MAX": 180, "MNT2_TYPE": 0, "SYSID_THISMAV": SYSID}
GREMSY_PARAMS = {**SERVO_PARAMS, "MNT1_TYPE": 6, "MNT1_PITCH_MIN": -120}
NO_MOUNT_PARAMS = {"SYSID_THISMAV": SYSID}  # a firmware without the mount library


@pytest.fixture
def link():
    opened = []

    def connect(peer):
        conn = mavlink2_connection(f"udpout:127.0.0.1:{peer.port}", 255, 190)
        opened.append(conn)
        return conn
    yield connect
    for conn in opened:
        conn.close()


def mount_check(config, peer, capsys, timeout_s=2.0):
    code = main(["mount-check", "--config", str(config),
                 "--connect", f"udpout:127.0.0.1:{peer.port}", "--timeout-s", str(timeout_s)])
    return code, capsys.readouterr()


def test_param_names_are_ardupilots():
    assert mount_param_names(2) == ("MNT2_TYPE", "MNT2_ROLL_MIN", "MNT2_ROLL_MAX",
                                    "MNT2_PITCH_MIN", "MNT2_PITCH_MAX", "MNT2_YAW_MIN",
                                    "MNT2_YAW_MAX")
    assert legacy_mount_param_names(1) == ("MNT_TYPE", "MNT_ANGMIN_ROL", "MNT_ANGMAX_ROL",
                                           "MNT_ANGMIN_TIL", "MNT_ANGMAX_TIL",
                                           "MNT_ANGMIN_PAN", "MNT_ANGMAX_PAN")
    assert legacy_mount_param_names(2) == ()


def test_servo_mount_reads_as_body_with_the_limits(autopilot, link, tmp_path, capsys):
    peer = autopilot(SERVO_PARAMS)
    conn = link(peer)
    assert wait_autopilot(conn, 2.0) == (SYSID, 1)
    read = read_mount_params(conn, 1, target_system=SYSID, timeout_s=2.0)
    assert read.values == {k: float(v) for k, v in SERVO_PARAMS.items() if k != "SYSID_THISMAV"}
    assert read.missing == ()
    interp = resolve_interpretation(GimbalMount(), read.values, "the link")
    assert interp.frame == "body" and "MNT1_TYPE=1 in the link" in interp.reason
    assert interp.limits_rad[1, 0] == pytest.approx(-1.5708, abs=1e-4)

    code, out = mount_check(gimbal_config(tmp_path), peer, capsys)
    assert code == 0, out.err
    assert f"system {SYSID}, component 1" in out.out
    assert "MNT1_TYPE=1 (Servo)" in out.out and "MNT1_ROLL_MIN=-30" in out.out
    assert "missing (no reply): none" in out.out
    assert "interpretation: body:" in out.out
    assert "MNT1_TYPE=1 in the autopilot's parameters over MAVLink" in out.out
    assert "roll [-30, 30] deg pitch [-90, 20] deg yaw [-180, 180] deg" in out.out


def test_smart_gimbal_reads_as_flags_and_a_configured_frame_is_questioned(
        autopilot, tmp_path, capsys):
    peer = autopilot(GREMSY_PARAMS)
    code, out = mount_check(gimbal_config(tmp_path), peer, capsys)
    assert code == 0, out.err
    assert "MNT1_TYPE=6 (Gremsy)" in out.out and "interpretation: flags:" in out.out
    assert "warning" not in out.out

    code, out = mount_check(gimbal_config(tmp_path, attitude_frame="body"), peer, capsys)
    assert code == 0 and "interpretation: body:" in out.out
    assert "warning: MNT1_TYPE=6 reads as 'flags' under attitude_frame: auto" in out.out
    assert "pitch [-120, 20] deg" in out.out


def test_unknown_parameters_leave_auto_to_the_fallback(autopilot, tmp_path, capsys):
    peer = autopilot(NO_MOUNT_PARAMS)
    code, out = mount_check(gimbal_config(tmp_path, auto_fallback="body"), peer, capsys,
                            timeout_s=0.3)
    assert code == 0, out.err
    assert "parameters read: none" in out.out
    assert "MNT1_TYPE, MNT1_ROLL_MIN" in out.out and "MNT_TYPE, MNT_ANGMIN_ROL" in out.out
    assert "interpretation: body:" in out.out
    assert "has no MNT1_TYPE parameter, so mount.auto_fallback='body' decides" in out.out
    assert "no servo limits known" in out.out
    assert peer.requests["MNT1_TYPE"] == 3  # asked, then twice more


def test_lossy_link_gets_every_parameter_on_the_retry(autopilot, link):
    peer = autopilot(SERVO_PARAMS, drop_first=True)
    conn = link(peer)
    system, component = wait_autopilot(conn, 2.0)
    names = mount_param_names(1)
    got = read_params(conn, names, target_system=system, target_component=component,
                      timeout_s=0.9, retries=2)
    assert got == {n: float(SERVO_PARAMS[n]) for n in names}
    assert all(peer.requests[n] == 2 for n in names)


def test_gcs_heartbeat_and_other_traffic_are_not_the_autopilot(autopilot, link):
    peer = autopilot(SERVO_PARAMS, noisy=True)
    conn = link(peer)
    assert wait_autopilot(conn, 2.0) == (SYSID, 1)
    got = read_params(conn, ["MNT1_TYPE", "MNT1_PITCH_MIN"], target_system=SYSID,
                      timeout_s=2.0)
    assert got == {"MNT1_TYPE": 1.0, "MNT1_PITCH_MIN": -90.0}  # not system 250's 99


def test_only_a_ground_station_is_no_autopilot(autopilot, link):
    peer = autopilot(SERVO_PARAMS, noisy=True)
    conn = link(peer)
    with pytest.raises(TelemetryError, match=r"no HEARTBEAT of an autopilot of system 3 .*"
                                        r"ignored: system 7 component 1, system 250"):
        wait_autopilot(conn, 0.3, system_id=3)


def test_a_fixed_mount_is_refused(tmp_path, capsys):
    config = write_config(tmp_path, mission_doc())
    assert main(["mount-check", "--config", str(config), "--connect", "udpin:127.0.0.1:0",
                 "--timeout-s", "0.1"]) == 2
    assert "mount.type: mount-check reads a gimbal mount's parameters" in capsys.readouterr().err
