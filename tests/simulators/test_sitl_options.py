"""pdcov-sitl fly's options end to end (real processes, real sockets, --speed 0, a short
survey): --wait-mission with `pdcov upload`, --autopilot px4, --camera-trigger with the
config's frame clock from captures, --gimbal-axes 2, and the autopilot faults that touch the
flight (GPS glitch, gimbal failure, reboot) as the tlog shows them. Every process is
started with a timeout and killed on failure."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("jsbsim")
os.environ["MAVLINK20"] = "1"

from pymavlink import mavutil

from pdcov.core.geodesy import Origin
from pdcov.core.mission import MissionItem
from pdcov.core.rotations import R_from_quat_wxyz
from pdcov.planning.plan import Plan, Waypoint
from pdcov.planning.plan_files import wpl_text
from pdcov.planning.plan_items import mission_items
from pdcov.telemetry.pose_csv import read_pose_csv
from pdcov_sitl.endpoint import TLOG_EPOCH_UNIX_S

BIN = Path(sys.executable).parent
TIMEOUT_S = 120
ORIGIN = Origin(39.35, -76.33, 5.0)
CONFIG = """\
vehicle_id: sim
origin: {lat_deg: 39.35, lon_deg: -76.33, ground_alt_msl_m: 5.0}
domain: {polygon_enu_m: [[-20, -20], [20, -20], [20, 20], [-20, 20]], cell_size_m: 1.0}
camera: {width_px: 640, height_px: 480, K: [[480, 0, 319.5], [0, 480, 239.5], [0, 0, 1]],
         distortion_model: plumb_bob, distortion_coeffs: [0, 0, 0, 0, 0], frame_rate_hz: 5}
mount: MOUNT
detector: illustrative
"""
GIMBAL = "{type: gimbal, attitude_frame: flags}"
PLAN = Plan((Waypoint(-15.0, -15.0, 10.0, 5.0), Waypoint(-15.0, 15.0, 10.0, 5.0),
             Waypoint(15.0, 15.0, 10.0, 5.0), Waypoint(15.0, -15.0, 10.0, 5.0)))


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    """A folder with the plan (plan.waypoints, and yaw30.waypoints commanding the gimbal
    30 deg right before the first waypoint) and configs (gimbal.yaml, capture.yaml)."""
    d = tmp_path_factory.mktemp("options")
    items = list(mission_items(PLAN, ORIGIN))
    (d / "plan.waypoints").write_text(wpl_text(tuple(items), ORIGIN))
    first_wp = next(i for i, it in enumerate(items) if it.command == 16)
    items.insert(first_wp, MissionItem(205, 2, param1=-90.0, param3=30.0))  # DO_MOUNT_CONTROL
    (d / "yaw30.waypoints").write_text(wpl_text(tuple(items), ORIGIN))
    (d / "gimbal.yaml").write_text(CONFIG.replace("MOUNT", GIMBAL))
    (d / "capture.yaml").write_text(CONFIG.replace("MOUNT", GIMBAL)
                                    + "log: {frame_source: capture}\n")
    return d


def _fly(files: Path, out: Path, *extra: str, config: str = "gimbal.yaml",
         plan: str = "plan.waypoints") -> Path:
    r = subprocess.run([str(BIN / "pdcov-sitl"), "fly", "--config", str(files / config),
                        "--plan", str(files / plan), "--out", str(out), "--speed", "0",
                        "--connect", "udpout:127.0.0.1:9", *extra],
                       capture_output=True, text=True, timeout=TIMEOUT_S)
    assert r.returncode == 0, r.stderr
    return out


def _messages(tlog: Path, *types: str) -> list[tuple[float, object]]:
    """(simulated s from the tlog stamp, message) of the given types, in order."""
    log = mavutil.mavlink_connection(str(tlog))
    out = []
    try:
        while (m := log.recv_match(type=list(types))) is not None:
            out.append((m._timestamp - TLOG_EPOCH_UNIX_S, m))
    finally:
        log.close()
    return out


def _agreement(config: Path, run: Path) -> tuple[float, int, int]:
    """`pdcov evaluate --log` of the tlog against `--poses` of truth.csv: the share of free
    cells within 0.02 P_D and the frames each evaluated."""
    grids = {}
    for source, path in (("--log", run / "flight.tlog"), ("--poses", run / "truth.csv")):
        out = run / f"eval{source}"
        r = subprocess.run([str(BIN / "pdcov"), "evaluate", "--config", str(config), source,
                            str(path), "--out", str(out), "--no-progress"],
                           capture_output=True, text=True, timeout=TIMEOUT_S)
        assert r.returncode == 0, r.stderr
        grids[source] = np.load(out / "grid.npz")
    a, b = grids["--log"], grids["--poses"]
    diff = np.abs(a["pd"] - b["pd"])[a["mask"]]
    return float((diff <= 0.02).mean()), int(a["frames"]), int(b["frames"])


def _passes_waypoints(run: Path) -> float:
    """The largest distance (m) of the flown camera track from the plan's waypoints."""
    r = np.array([p.r_cam_enu for p in read_pose_csv(run / "truth.csv")])
    return max(float(np.min(np.linalg.norm(r[:, :2] - xy, axis=1))) for xy in PLAN.xy_enu_m)


def test_wait_mission_flies_what_pdcov_upload_sends(files: Path, tmp_path: Path) -> None:
    sim = subprocess.Popen([str(BIN / "pdcov-sitl"), "fly", "--config",
                            str(files / "gimbal.yaml"), "--wait-mission", "--out",
                            str(tmp_path / "run"), "--speed", "0", "--connect",
                            "udpin:127.0.0.1:0"], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    try:
        line = sim.stderr.readline()  # pdcov-sitl: MAVLink on UDP, listening on HOST:PORT
        port = int(re.search(r"listening on 127\.0\.0\.1:(\d+)", line).group(1))
        up = subprocess.run([str(BIN / "pdcov"), "upload", "--connect",
                             f"udpout:127.0.0.1:{port}", str(files / "plan.waypoints"),
                             "--timeout-s", "20"], capture_output=True, text=True,
                            timeout=60)
        assert up.returncode == 0, up.stdout + up.stderr
        out, err = sim.communicate(timeout=TIMEOUT_S)
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.communicate()
    assert sim.returncode == 0, err
    assert "flew" in out
    heartbeats = _messages(tmp_path / "run" / "flight.tlog", "HEARTBEAT")
    modes = [m.custom_mode for _, m in heartbeats if m.get_srcComponent() == 1]
    waited_s = next(t for t, m in heartbeats if m.custom_mode == 3)  # AUTO once uploaded
    print(f"waited {waited_s:.1f} s on the ground for the upload; flew within "
          f"{_passes_waypoints(tmp_path / 'run'):.2f} m of every waypoint")
    assert modes[0] == 0 and 3 in modes and 9 in modes  # ground, AUTO, LAND
    assert _passes_waypoints(tmp_path / "run") < 2.0


def test_px4_heartbeat_modes_rates_and_live_agrees_with_truth(files: Path, tmp_path: Path
                                                               ) -> None:
    run = _fly(files, tmp_path / "px4", "--autopilot", "px4", "--gimbal", "device-earth")
    msgs = _messages(run / "flight.tlog", "HEARTBEAT", "ATTITUDE")
    beats = [m for _, m in msgs if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1]
    assert {m.autopilot for m in beats} == {12}  # MAV_AUTOPILOT_PX4
    modes = {((m.custom_mode >> 16) & 0xFF, m.custom_mode >> 24) for m in beats}
    assert {(4, 2), (4, 4), (4, 5), (4, 6)} <= modes  # AUTO: TAKEOFF, MISSION, RTL, LAND
    t_att = np.array([t for t, m in msgs if m.get_type() == "ATTITUDE"])
    rate_hz = (len(t_att) - 1) / (t_att[-1] - t_att[0])
    share, n_log, n_truth = _agreement(files / "gimbal.yaml", run)
    print(f"px4: ATTITUDE at {rate_hz:.1f} Hz; evaluate --log vs --poses: {share:.2%} of "
          f"cells within 0.02 P_D, {n_log} vs {n_truth} frames")
    assert rate_hz == pytest.approx(50.0, rel=0.05)
    assert share >= 0.99 and abs(n_log - n_truth) <= 2


def test_camera_trigger_captures_at_the_frame_rate_and_clock_the_frames(files: Path,
                                                                        tmp_path: Path) -> None:
    run = _fly(files, tmp_path / "trigger", "--camera-trigger")
    caps = [m for _, m in _messages(run / "flight.tlog", "CAMERA_IMAGE_CAPTURED")]
    truth = read_pose_csv(run / "truth.csv")
    t_cap = np.array([m.time_boot_ms / 1000.0 for m in caps])
    assert len(caps) == len(truth) > 100
    assert [m.image_index for m in caps] == list(range(len(caps)))
    assert all(m.capture_result == 1 for m in caps)
    assert np.allclose(np.diff(t_cap), 0.2, atol=0.0011)  # 5 frames/s, ms resolution
    assert np.allclose(t_cap, [p.t_s for p in truth], atol=0.0006)
    # The capture's position is the frame's (truth: camera centre, no lever arm here).
    r0 = truth[len(truth) // 2].r_cam_enu
    c0 = caps[len(truth) // 2]
    assert c0.relative_alt / 1000.0 == pytest.approx(r0[2], abs=0.01)
    share, n_log, n_truth = _agreement(files / "capture.yaml", run)
    print(f"camera trigger: {len(caps)} captures every 0.2 s; evaluate --log with "
          f"frame_source capture vs --poses: {share:.2%} within 0.02 P_D, {n_log} vs "
          f"{n_truth} frames")
    assert share >= 0.99 and n_log == n_truth


@pytest.mark.parametrize("axes", [2, 3])
def test_gimbal_axes(files: Path, tmp_path: Path, axes: int) -> None:
    """The plan turns the camera 30 deg right of the heading: a 3-axis gimbal does, a
    2-axis one (no yaw motor) cannot and reports yaw 0 in the vehicle frame."""
    run = _fly(files, tmp_path / f"axes{axes}", "--gimbal", "ardupilot-device",
               "--gimbal-axes", str(axes), plan="yaw30.waypoints")
    status = [(t, m) for t, m in _messages(run / "flight.tlog",
                                           "GIMBAL_DEVICE_ATTITUDE_STATUS")]
    # At nadir the Euler yaw is undefined (gimbal lock): the yaw is where the gimbal's
    # y axis (the image's right) points, (-sin yaw, cos yaw, 0) of Rz(yaw) Ry(-90 deg).
    yaw_deg = []
    for t, m in status:
        if 15.0 < t < 30.0:  # surveying
            R = R_from_quat_wxyz(np.array(m.q))
            yaw_deg.append(math.degrees(math.atan2(-R[0, 1], R[1, 1])))
    truth = read_pose_csv(run / "truth.csv")
    share, n_log, n_truth = _agreement(files / "gimbal.yaml", run)
    print(f"{axes} axes: reported yaw in the vehicle frame {np.median(yaw_deg):.1f} deg; "
          f"evaluate --log vs --poses {share:.2%} within 0.02 P_D")
    assert len(truth) > 100
    want = 30.0 if axes == 3 else 0.0
    assert abs(np.median(yaw_deg) - want) < 2.0
    assert share >= 0.99


def test_faults_that_touch_the_flight_as_the_tlog_shows_them(files: Path, tmp_path: Path
                                                             ) -> None:
    run = _fly(files, tmp_path / "faults", "--gimbal", "ardupilot-device", "--faults",
               "gps_glitch=14+3:20,gimbal_fail=20+2,reboot=26+2")
    msgs = _messages(run / "flight.tlog", "GLOBAL_POSITION_INT", "GPS_RAW_INT", "ATTITUDE",
                     "GIMBAL_DEVICE_ATTITUDE_STATUS")
    truth = read_pose_csv(run / "truth.csv")
    t_truth = np.array([p.t_s for p in truth])
    y_truth = np.array([p.r_cam_enu[1] for p in truth])

    def north_error_m(t: float, lat_e7: int) -> float:
        return (lat_e7 * 1e-7 - ORIGIN.lat_deg) * 111_000.0 - np.interp(t, t_truth, y_truth)

    err = [(t, north_error_m(t, m.lat)) for t, m in msgs if m.get_type() == "GLOBAL_POSITION_INT"]
    during = [e for t, e in err if 14.2 < t < 16.9]
    outside = [e for t, e in err if 10.0 < t < 13.9 or 17.2 < t < 25.0]
    gimbal = [(t, m.failure_flags) for t, m in msgs
              if m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"]
    boot = [(t, m.time_boot_ms) for t, m in msgs if m.get_type() == "ATTITUDE"]
    print(f"GPS glitch: reported {np.mean(during):.1f} m north of the truth during it, "
          f"{np.max(np.abs(outside)):.2f} m outside it; gimbal failure flags from "
          f"{min(t for t, f in gimbal if f):.2f} s, last status at {gimbal[-1][0]:.2f} s")
    assert during and min(during) > 19.0 and max(during) < 21.0
    assert max(np.abs(outside)) < 0.5  # recovered; the EKF position is the true one
    assert all(f == 0 for t, f in gimbal if t < 19.95)
    assert any(f != 0 for t, f in gimbal if 20.0 <= t < 22.0)
    assert gimbal[-1][0] < 22.1  # then silent for good
    # Reboot: silent for 2 s (booting), then time_boot_ms counts from the restart.
    assert not [t for t, _ in boot if 26.05 < t < 27.95]
    after = [(t, ms) for t, ms in boot if t > 28.0]
    assert all(abs(ms - t * 1000) < 60 for t, ms in boot if t < 26.0)
    assert after and all(abs(ms - (t - 26.0) * 1000) < 60 for t, ms in after)
    # The flight itself carries on: it still passes every waypoint and lands at home.
    assert _passes_waypoints(run) < 2.0
    assert np.linalg.norm(truth[-1].r_cam_enu[:2]) < 0.5
    # And pdcov evaluate --log reads the faulty tlog without failing.
    r = subprocess.run([str(BIN / "pdcov"), "evaluate", "--config", str(files / "gimbal.yaml"),
                        "--log", str(run / "flight.tlog"), "--out", str(run / "eval"),
                        "--no-progress"], capture_output=True, text=True, timeout=TIMEOUT_S)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr

