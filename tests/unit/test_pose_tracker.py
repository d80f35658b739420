"""Poses from synthetic tlogs equal the known poses; gaps, captures, live feed, pose CSV."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from pdcov.core.geodesy import Origin
from pdcov.core.mount import GimbalMount
from pdcov.core.pose import (
    GIMBAL_FLAG_YAW_IN_EARTH_FRAME,
    GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME,
    FixedMount,
    GimbalFrame,
    R_ned_gimbal_from_quat,
    camera_pose,
    fixed_mount_pose,
)
from pdcov.core.rotations import R_from_euler_zyx_many, quat_wxyz_from_euler_zyx
from pdcov.errors import InputFileError, TelemetryError
from pdcov.flight.frame_decision import Framing
from pdcov.flight.log_frames import poses_from_log
from pdcov.telemetry.frame_policy import FrameSource
from pdcov.telemetry.pose_csv import read_pose_csv, write_pose_csv
from pdcov.telemetry.pose_tracker import PoseTracker
from pdcov.telemetry.samples import AttitudeSample, CaptureSample, GimbalSample, PositionSample
from tests.support.mavlink_fixtures import KnownFlight, samples_from_flight, write_tlog

ORIGIN = Origin(-35.363261, 149.165230, 584.0)
RATE_HZ = 20.0  # telemetry rate; frames at 5 Hz fall on telemetry samples


def known_flight(n: int = 200, gimbal_flags: int | None = None) -> KnownFlight:
    t = 1.0 + np.arange(n) / RATE_HZ
    s = np.linspace(0, 1, n)
    R = R_from_euler_zyx_many(0.2 * np.sin(6 * s), -0.3 * s, 2.5 * s - 1.0)
    r = np.stack([40 * s, 10 * np.sin(3 * s), 10 + 2 * s], axis=1)
    q_g = flags = None
    if gimbal_flags is not None:
        q_g = quat_wxyz_from_euler_zyx(0.05 * np.cos(5 * s), -1.2 - 0.3 * s, 0.4 * s)
        flags = [gimbal_flags] * n
    return KnownFlight(ORIGIN, t, R, r, q_g, flags)


def evaluate(path: Path, mount: FixedMount | GimbalMount, *, max_gap_s: float = 1.0,
             frame_source: str = "rate", ground_alt_msl_m: float | None = None):
    return poses_from_log(path, Framing(mount, 5.0, frame_source=FrameSource(frame_source),
                                        max_gap_s=max_gap_s),
                          origin_lat_deg=ORIGIN.lat_deg, origin_lon_deg=ORIGIN.lon_deg,
                          ground_alt_msl_m=ground_alt_msl_m)


def check_equal(poses: tuple, expected: list) -> None:
    assert len(poses) == len(expected)
    for p, e in zip(poses, expected, strict=True):
        assert p.t_s == pytest.approx(e.t_s, abs=1e-9)
        np.testing.assert_allclose(p.r_cam_enu, e.r_cam_enu, atol=0.02)  # degE7, mm
        np.testing.assert_allclose(p.R_enu_cam, e.R_enu_cam, atol=1e-5)


def test_fixed_mount_poses_equal_known(tmp_path: Path) -> None:
    f = known_flight()
    mount = FixedMount(0.0, np.radians(-80), 0.1, (0.2, 0.0, 0.1))
    lp = evaluate(write_tlog(tmp_path / "f.tlog", samples_from_flight(f)), mount)
    every = slice(None, None, int(RATE_HZ / 5))
    expected = [fixed_mount_pose(R, r, mount, t) for R, r, t in
                zip(f.R_ned_body[every], f.r_body_enu[every], f.t_s[every], strict=True)]
    check_equal(lp.poses, expected)
    assert lp.origin == ORIGIN  # ground altitude from HOME_POSITION
    assert any("HOME_POSITION" in line for line in lp.summary_lines)
    assert lp.track_enu.shape == (200, 3)


@pytest.mark.parametrize("flags, frame", [
    (GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME | 12, GimbalFrame.VEHICLE),
    (GIMBAL_FLAG_YAW_IN_EARTH_FRAME | 12, GimbalFrame.EARTH),
])
def test_gimbal_poses_equal_known(tmp_path: Path, flags: int, frame: GimbalFrame) -> None:
    f = known_flight(gimbal_flags=flags)
    mount = GimbalMount(attitude_frame="flags", lever_arm_frd_m=(0.1, 0.0, 0.2))
    lp = evaluate(write_tlog(tmp_path / "g.tlog", samples_from_flight(f)), mount)
    every = slice(None, None, int(RATE_HZ / 5))
    expected = [camera_pose(R, r, R_ned_gimbal_from_quat(q, frame, R), mount.lever_arm_frd_m, t)
                for R, r, q, t in zip(f.R_ned_body[every], f.r_body_enu[every],
                                      f.q_gimbal_wxyz[every], f.t_s[every], strict=True)]
    check_equal(lp.poses, expected)
    assert set(lp.interpretation) == {"flags:" + frame.value}
    assert lp.trusted.all()


def test_body_interpretation_equals_body_frame(tmp_path: Path) -> None:
    f = known_flight(gimbal_flags=GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME)
    mount = GimbalMount(attitude_frame="body", servo_axis_order=("yaw", "pitch", "roll"))
    lp = evaluate(write_tlog(tmp_path / "b.tlog", samples_from_flight(f)), mount)
    every = slice(None, None, int(RATE_HZ / 5))
    expected = [camera_pose(R, r, R_ned_gimbal_from_quat(q, GimbalFrame.BODY, R), (0, 0, 0), t)
                for R, r, q, t in zip(f.R_ned_body[every], f.r_body_enu[every],
                                      f.q_gimbal_wxyz[every], f.t_s[every], strict=True)]
    check_equal(lp.poses, expected)


def test_hand_check_level_north_nadir(tmp_path: Path) -> None:
    n = 20
    f = KnownFlight(ORIGIN, 1.0 + np.arange(n) / RATE_HZ, np.tile(np.eye(3), (n, 1, 1)),
                    np.tile([3.0, 4.0, 10.0], (n, 1)))
    lp = evaluate(write_tlog(tmp_path / "h.tlog", samples_from_flight(f)), FixedMount())
    p = lp.poses[0]
    np.testing.assert_allclose(p.optical_axis_enu, [0, 0, -1], atol=1e-6)
    np.testing.assert_allclose(p.R_enu_cam[:, 0], [1, 0, 0], atol=1e-6)  # image right: east
    np.testing.assert_allclose(p.R_enu_cam[:, 1], [0, -1, 0], atol=1e-6)  # image down: south
    np.testing.assert_allclose(p.r_cam_enu, [3, 4, 10], atol=0.02)


def test_gaps_skip_frames_and_are_reported(tmp_path: Path) -> None:
    f = known_flight()
    samples = [s for s in samples_from_flight(f) if not 4.0 < getattr(s, "t_s", 0) < 6.5]
    lp = evaluate(write_tlog(tmp_path / "gap.tlog", samples), FixedMount(), max_gap_s=1.0)
    t = np.array([p.t_s for p in lp.poses])
    assert not np.any((t > 4.0) & (t < 6.5))
    assert len(lp.skipped_t_s) == 12
    line = next(x for x in lp.summary_lines if x.startswith("skipped"))
    assert "4.20-6.40 s" in line and "attitude gap" in line
    # A longer gap limit bridges it.
    assert len(evaluate(tmp_path / "gap.tlog", FixedMount(), max_gap_s=3.0).poses) == 50


def test_capture_frames(tmp_path: Path) -> None:
    f = known_flight()
    samples = samples_from_flight(f) + [CaptureSample(t, i, "CAMERA_IMAGE_CAPTURED")
                                        for i, t in enumerate((2.0, 3.5, 7.25))]
    path = write_tlog(tmp_path / "c.tlog", samples)
    lp = evaluate(path, FixedMount(), frame_source="capture")
    assert [p.t_s for p in lp.poses] == pytest.approx([2.0, 3.5, 7.25])
    with pytest.raises(TelemetryError, match="no capture events"):
        evaluate(write_tlog(tmp_path / "n.tlog", samples_from_flight(f)), FixedMount(),
                 frame_source="capture")


def test_untrusted_policy(tmp_path: Path) -> None:
    f = known_flight(gimbal_flags=GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME)
    samples = samples_from_flight(f)
    for s in samples[:60]:  # the first 20 gimbal reports claim an encoder error
        if hasattr(s, "failure_flags"):
            object.__setattr__(s, "failure_flags", 8)
    path = write_tlog(tmp_path / "u.tlog", samples)
    skip = evaluate(path, GimbalMount(attitude_frame="flags"))
    use = evaluate(path, GimbalMount(attitude_frame="flags", untrusted="use"))
    assert len(use.poses) == 50 and len(skip.poses) < 50
    assert (~use.trusted).sum() == 50 - len(skip.poses)
    assert any("gimbal failure flags" in x for x in skip.summary_lines)


def test_live_feed_equals_offline(tmp_path: Path) -> None:
    f = known_flight(gimbal_flags=GIMBAL_FLAG_YAW_IN_EARTH_FRAME)
    mount = GimbalMount(attitude_frame="flags")
    lp = evaluate(write_tlog(tmp_path / "l.tlog", samples_from_flight(f)), mount,
                  ground_alt_msl_m=ORIGIN.ground_alt_msl_m)
    tracker = PoseTracker(ORIGIN, mount, max_gap_s=1.0, history_s=5.0)
    live = []
    samples = sorted(samples_from_flight(f, home=False), key=lambda s: s.t_s)
    frames = iter([p.t_s for p in lp.poses])
    next_frame = next(frames)
    for s in samples:
        kind = type(s).__name__
        {"AttitudeSample": tracker.add_attitude, "PositionSample": tracker.add_position,
         "GimbalSample": tracker.add_gimbal}[kind](s)
        while next_frame is not None and s.t_s >= next_frame + 0.06:
            live.append(tracker.pose_at(next_frame).pose)
            next_frame = next(frames, None)
    assert len(live) >= 40
    for a, b in zip(live, lp.poses, strict=False):
        np.testing.assert_allclose(a.R_enu_cam, b.R_enu_cam, atol=1e-4)
        np.testing.assert_allclose(a.r_cam_enu, b.r_cam_enu, atol=0.02)
    assert tracker.pose_at(1000.0).pose is None


def test_live_gimbal_reports_without_quaternion_are_counted_not_raised() -> None:
    """A gimbal that first sends NaN quaternions (no attitude yet) leaves the live tracker
    with no usable gimbal report: frames are skipped, the reports counted, nothing raised."""
    tracker = PoseTracker(ORIGIN, GimbalMount(attitude_frame="flags"))
    nan = float("nan")
    for t in (0.0, 0.1):
        tracker.add_attitude(AttitudeSample(t, (1.0, 0.0, 0.0, 0.0)))
        tracker.add_position(PositionSample(t, ORIGIN.lat_deg, ORIGIN.lon_deg, 600.0))
        tracker.add_gimbal(GimbalSample(t, (nan, nan, nan, nan),
                                        GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME))
    result = tracker.pose_at(0.05)
    assert result.pose is None and result.reason == "outside the gimbal samples"
    assert tracker.dropped_gimbal_reports == 2
    tracker.add_gimbal(GimbalSample(0.2, (1.0, 0.0, 0.0, 0.0),
                                    GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME))
    tracker.add_attitude(AttitudeSample(0.2, (1.0, 0.0, 0.0, 0.0)))
    tracker.add_position(PositionSample(0.2, ORIGIN.lat_deg, ORIGIN.lon_deg, 600.0))
    assert tracker.pose_at(0.2).pose is not None


def test_pose_csv_round_trip_is_exact(tmp_path: Path) -> None:
    f = known_flight(gimbal_flags=GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME)
    lp = evaluate(write_tlog(tmp_path / "r.tlog", samples_from_flight(f)),
                  GimbalMount(attitude_frame="flags"))
    out = tmp_path / "poses.csv"
    write_pose_csv(out, lp)
    header = out.read_text().splitlines()[0].split(",")
    assert header[:8] == ["t_s", "x_m", "y_m", "z_m", "qw", "qx", "qy", "qz"]
    assert {"roll_deg", "gimbal_qw", "interpretation", "trusted"} <= set(header)
    back = read_pose_csv(out)
    for a, b in zip(back, lp.poses, strict=True):
        assert a.t_s == b.t_s
        np.testing.assert_array_equal(a.R_enu_cam, b.R_enu_cam)
        np.testing.assert_array_equal(a.r_cam_enu, b.r_cam_enu)
    assert not list(tmp_path.glob(".poses.csv.*"))  # no temp file left


@pytest.mark.parametrize("body, match", [
    ("t,x,y,z,a,b,c,d\n", ":1: expected the header"),
    ("t_s,x_m,y_m,z_m,qw,qx,qy,qz\n0,0,0,10,1,0,0,0\n1,0,nan,10,1,0,0,0\n", ":3: y_m"),
    ("t_s,x_m,y_m,z_m,qw,qx,qy,qz\n0,0,0,10,0.9,0,0,0\n", ":2: quaternion"),
    ("t_s,x_m,y_m,z_m,qw,qx,qy,qz\n0,0,zero,10,1,0,0,0\n", ":2: expected 8 numbers"),
    ("t_s,x_m,y_m,z_m,qw,qx,qy,qz\n", "no pose rows"),
])
def test_pose_csv_errors_name_file_and_line(tmp_path: Path, body: str, match: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(body)
    with pytest.raises(InputFileError, match=match) as exc:
        read_pose_csv(path)
    assert str(path) in str(exc.value)


def test_frames_at_speed() -> None:
    """10 min at 30 fps (18000 frames): pose computation stays well under 100 us/frame."""
    n = 12000
    f = known_flight(n=n, gimbal_flags=GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME)
    tracker = PoseTracker(ORIGIN, GimbalMount(attitude_frame="body"))
    for s in samples_from_flight(f, home=False):
        {"AttitudeSample": tracker.add_attitude, "PositionSample": tracker.add_position,
         "GimbalSample": tracker.add_gimbal}[type(s).__name__](s)
    t = np.linspace(f.t_s[0], f.t_s[-1], 18000)
    start = time.perf_counter()
    b = tracker.frames_at(t)
    elapsed = time.perf_counter() - start
    assert b.valid.all()
    assert elapsed / len(t) < 100e-6
