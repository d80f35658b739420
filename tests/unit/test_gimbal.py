"""Gimbal interpretation: flags vs body-frame servo demand, trust verdicts, config."""

from __future__ import annotations

import numpy as np
import pytest

from pdcov.core.rotations import R_from_euler_zyx, quat_wxyz_from_euler_zyx
from pdcov.errors import ConfigError
from pdcov.telemetry.gimbal import (
    GimbalMount,
    gimbal_attitude,
    interpret_gimbal,
    preferred_gimbal_source,
    resolve_interpretation,
)

DEG = np.pi / 180
DOWN = np.array([0.0, 0.0, 1.0])  # NED
VEHICLE, EARTH, YAW_LOCK = 32, 64, 16
SERVO_PARAMS = {"MNT1_TYPE": 1, "MNT1_ROLL_MIN": -30, "MNT1_ROLL_MAX": 30,
                "MNT1_PITCH_MIN": -90, "MNT1_PITCH_MAX": 20, "MNT1_YAW_MIN": -180,
                "MNT1_YAW_MAX": 180}


def q_deg(roll: float, pitch: float, yaw: float) -> np.ndarray:
    return quat_wxyz_from_euler_zyx(roll * DEG, pitch * DEG, yaw * DEG)


def axis(R: np.ndarray) -> np.ndarray:
    return R[:, 0]  # gimbal x = optical axis


def off_down_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(axis(R) @ DOWN, -1, 1))))


def interp(frame: str, **kw: object):
    return resolve_interpretation(GimbalMount(attitude_frame=frame, **kw), {})


def test_flags_vehicle_frame_ignores_vehicle_pitch() -> None:
    R_body = R_from_euler_zyx(0.0, -20 * DEG, 90 * DEG)
    v = gimbal_attitude(q_deg(0, -70, 0), VEHICLE | 12, 0, R_body, interp("flags"))
    # Read at its flags' word: roll/pitch relative to the horizon -> 20 deg short of nadir.
    assert off_down_deg(v.R_ned_gimbal) == pytest.approx(20.0, abs=1e-5)
    assert v.trusted


def test_body_frame_composes_with_vehicle_attitude() -> None:
    # The servo-gimbal case of issue 6: nose down 20 deg, servo demand -70 = nadir.
    R_body = R_from_euler_zyx(0.0, -20 * DEG, 90 * DEG)
    for order in (("yaw", "roll", "pitch"), ("yaw", "pitch", "roll")):
        v = gimbal_attitude(q_deg(0, -70, 0), VEHICLE | 12, 0, R_body,
                            interp("body", servo_axis_order=order))
        assert off_down_deg(v.R_ned_gimbal) == pytest.approx(0.0, abs=1e-5)


def test_vehicle_frame_heading_and_earth_frame() -> None:
    R_body = R_from_euler_zyx(0.0, 0.0, 90 * DEG)
    forward = gimbal_attitude(q_deg(0, 0, 0), VEHICLE, 0, R_body, interp("flags"))
    np.testing.assert_allclose(axis(forward.R_ned_gimbal), [0, 1, 0], atol=1e-12)  # east
    earth = gimbal_attitude(q_deg(0, 0, 30), EARTH, 0, R_body, interp("flags"))
    np.testing.assert_allclose(axis(earth.R_ned_gimbal),
                               [np.cos(30 * DEG), np.sin(30 * DEG), 0], atol=1e-12)
    # Neither YAW_IN flag: YAW_LOCK means earth frame (common.xml backwards compatibility).
    locked = gimbal_attitude(q_deg(0, 0, 30), YAW_LOCK, 0, R_body, interp("flags"))
    np.testing.assert_allclose(locked.R_ned_gimbal, earth.R_ned_gimbal, atol=1e-12)
    follow = gimbal_attitude(q_deg(0, 0, 30), 0, 0, R_body, interp("flags"))
    np.testing.assert_allclose(axis(follow.R_ned_gimbal),
                               [np.cos(120 * DEG), np.sin(120 * DEG), 0], atol=1e-12)


def test_yaw_roll_pitch_servos_compensate_vehicle_roll_at_nadir() -> None:
    # ArduPilot subtracts the vehicle's roll and pitch; with the roll servo outside the tilt
    # servo that is exact: Ry(p)Rx(r) . Rx(-r)Ry(-90-p) = Ry(-90).
    R_body = R_from_euler_zyx(15 * DEG, -10 * DEG, 0.0)
    v = gimbal_attitude(q_deg(-15, -80, 0), VEHICLE | 12, 0, R_body, interp("body"))
    assert off_down_deg(v.R_ned_gimbal) == pytest.approx(0.0, abs=1e-5)


def test_demand_beyond_limit_is_clipped_and_untrusted() -> None:
    it = resolve_interpretation(GimbalMount(attitude_frame="body"), SERVO_PARAMS)
    R_body = R_from_euler_zyx(0.0, 20 * DEG, 0.0)  # nose up 20: nadir needs -110
    v = gimbal_attitude(q_deg(0, -110, 0), VEHICLE | 12, 0, R_body, it)
    assert not v.trusted and v.reason == "servo at pitch limit"
    # The servo stops at -90 in the body: nose up, the belly and the camera look 20 deg
    # ahead of nadir.
    assert off_down_deg(v.R_ned_gimbal) == pytest.approx(20.0, abs=1e-5)
    assert axis(v.R_ned_gimbal)[0] > 0


def test_demand_at_limit_is_counted_but_trusted() -> None:
    it = resolve_interpretation(GimbalMount(attitude_frame="body"), SERVO_PARAMS)
    out = interpret_gimbal(q_deg(0, -90, 0)[None], [44], [0], np.eye(3)[None], it)
    assert out.trusted[0] and out.at_limit[0]
    inside = interpret_gimbal(q_deg(0, -60, 0)[None], [44], [0], np.eye(3)[None], it)
    assert inside.trusted[0] and not inside.at_limit[0]


def test_failure_flags_norm_and_retract() -> None:
    it = interp("flags")
    q = q_deg(0, -45, 0)
    assert not gimbal_attitude(q, VEHICLE, 8, np.eye(3), it).trusted  # encoder error
    assert gimbal_attitude(q, VEHICLE, 2, np.eye(3), it).trusted  # at pitch limit: measured
    bad = gimbal_attitude(q * 1.01, VEHICLE, 0, np.eye(3), it)
    assert not bad.trusted and "not unit" in bad.reason
    assert not gimbal_attitude(q, VEHICLE | 1, 0, np.eye(3), it).trusted
    with pytest.raises(ValueError):
        gimbal_attitude([np.nan] * 4, VEHICLE, 0, np.eye(3), it)


def test_gimbal_lock_report_keeps_the_optical_axis() -> None:
    # Pitch -90: roll and yaw are one rotation about the vertical; the optical axis is
    # body-down whichever way the quaternion is split.
    it = interp("body", servo_axis_order=("yaw", "pitch", "roll"))
    v = gimbal_attitude(q_deg(40, -90, -70), VEHICLE, 0, np.eye(3), it)
    assert off_down_deg(v.R_ned_gimbal) == pytest.approx(0.0, abs=1e-5)


def test_auto_reads_mount_type() -> None:
    auto = GimbalMount()
    servo = resolve_interpretation(auto, SERVO_PARAMS)
    assert servo.frame == "body" and "MNT1_TYPE=1" in servo.reason
    np.testing.assert_allclose(np.degrees(servo.limits_rad[1]), [-90, 20])
    assert resolve_interpretation(auto, {"MNT1_TYPE": 6}).frame == "flags"
    fallback = resolve_interpretation(auto, {}, "the tlog")
    assert fallback.frame == "flags" and "no MNT1_TYPE" in fallback.reason
    assert resolve_interpretation(GimbalMount(auto_fallback="body"), {}).frame == "body"
    old = resolve_interpretation(auto, {"MNT_TYPE": 1, "MNT_ANGMIN_TIL": -4500,
                                        "MNT_ANGMAX_TIL": 4500, "MNT_ANGMIN_ROL": -4500,
                                        "MNT_ANGMAX_ROL": 4500, "MNT_ANGMIN_PAN": -4500,
                                        "MNT_ANGMAX_PAN": 4500})
    assert old.frame == "body"
    np.testing.assert_allclose(np.degrees(old.limits_rad[1]), [-45, 45])


def test_from_config_and_errors() -> None:
    m = GimbalMount.from_config({"type": "gimbal", "attitude_frame": "body",
                                 "servo_axis_order": "yaw_pitch_roll",
                                 "pitch_limits_deg": [-90, 20], "untrusted": "use",
                                 "lever_arm_frd_m": [0.1, 0, 0.05]}, "m.yaml")
    assert m.servo_axis_order == ("yaw", "pitch", "roll") and m.pitch_limits_deg == (-90, 20)
    assert m.lever_arm_frd_m == (0.1, 0.0, 0.05)
    cases = [({"attitude_frame": "sideways"}, "attitude_frame"),
             ({"colour": 1}, "mount.colour"),
             ({"pitch_limits_deg": [20, -90]}, "pitch_limits_deg"),
             ({"servo_axis_order": "yaw_yaw_roll"}, "servo_axis_order"),
             ({"lever_arm_frd_m": [0, 0]}, "lever_arm_frd_m"),
             ({"untrusted": "maybe"}, "untrusted")]
    for doc, key in cases:
        with pytest.raises(ConfigError, match=key) as exc:
            GimbalMount.from_config({"type": "gimbal", **doc}, "m.yaml")
        assert "m.yaml" in str(exc.value)


def test_preferred_source() -> None:
    ap, dev = (1, 1, 1), (1, 154, 0)
    assert preferred_gimbal_source({ap: 44, dev: 32}) == dev
    assert preferred_gimbal_source({ap: 44, dev: 12}) == ap  # device without YAW_IN flag
    assert preferred_gimbal_source({(1, 1, 2): 44, ap: 44}) == ap
