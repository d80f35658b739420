"""Inputs of `pdcov evaluate` for its tests: the mission document (a 40 m square with an
obstacle, a 640x480 camera at 5 frames/s), a known 20 s flight and the camera poses it
must give, pose CSVs, and the CLI run in process (``run``) or as a process (``cli``, for
the e2e tests: a clean failure is exit 2 without a traceback)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

from pdcov.cli import main
from pdcov.core.geodesy import Origin
from pdcov.core.pose import GimbalFrame, R_ned_gimbal_from_quat, camera_pose, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx, R_from_euler_zyx_many, quat_wxyz_from_R
from tests.support.mavlink_fixtures import KnownFlight

ORIGIN = Origin(39.35, -76.33, 5.0)
RATE_HZ = 5.0


def mission_doc(mount: dict | None = None, **extra) -> dict:
    doc = {
        "vehicle_id": "uav1",
        "origin": {"lat_deg": ORIGIN.lat_deg, "lon_deg": ORIGIN.lon_deg,
                   "ground_alt_msl_m": ORIGIN.ground_alt_msl_m},
        "domain": {"polygon_enu_m": [[0, 0], [40, 0], [40, 40], [0, 40]],
                   "obstacles_enu_m": [[[18, 18], [22, 18], [22, 22], [18, 22]]],
                   "cell_size_m": 1.0},
        "camera": {"width_px": 640, "height_px": 480,
                   "K": [[480, 0, 319.5], [0, 480, 239.5], [0, 0, 1]],
                   "distortion_model": "plumb_bob", "distortion_coeffs": [-0.05, 0.01, 0, 0, 0],
                   "frame_rate_hz": RATE_HZ},
        "mount": mount or {"type": "fixed", "roll_deg": 0, "pitch_deg": -90, "yaw_deg": 0},
        "detector": "illustrative",
        "thresholds": [0.5, 0.7, 0.8],
    }
    doc.update(extra)
    return doc


def write_config(tmp_path: Path, doc: dict, name: str = "mission.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc))
    return path


def known_flight(gimbal_flags: int | None = None) -> KnownFlight:
    """A 20 s pass north along x = 20 m at 8-12 m height with some roll, pitch and yaw."""
    t = np.arange(0.0, 20.0 + 1e-9, 1 / RATE_HZ)
    r = np.c_[20 + 3 * np.sin(t / 3), 2 * t, 10 + 2 * np.sin(t / 5)]
    R = R_from_euler_zyx_many(0.05 * np.sin(t), -0.1 + 0.03 * np.cos(t), 0.2 * np.sin(t / 4))
    q = None
    if gimbal_flags is not None:
        q = np.array([quat_wxyz_from_R(R_from_euler_zyx(0.02, -1.2 + 0.1 * np.sin(x), 0.3))
                      for x in t])
    flags = None if q is None else [gimbal_flags] * len(t)
    return KnownFlight(ORIGIN, t, R, r, q, flags)


def expected_poses(flight: KnownFlight, frame: GimbalFrame | None):
    poses = []
    for i, t in enumerate(flight.t_s):
        if frame is None:
            from pdcov.core.pose import FixedMount
            poses.append(fixed_mount_pose(flight.R_ned_body[i], flight.r_body_enu[i],
                                          FixedMount(), float(t)))
        else:
            R_ng = R_ned_gimbal_from_quat(flight.q_gimbal_wxyz[i], frame, flight.R_ned_body[i])
            poses.append(camera_pose(flight.R_ned_body[i], flight.r_body_enu[i], R_ng,
                                     t_s=float(t)))
    return poses


def write_pose_csv(path: Path, poses) -> Path:
    lines = ["t_s,x_m,y_m,z_m,qw,qx,qy,qz"]
    for p in poses:
        lines.append(",".join(repr(float(v)) for v in
                              (p.t_s, *p.r_cam_enu, *p.q_enu_cam_wxyz)))
    path.write_text("\n".join(lines) + "\n")
    return path


def run(*argv: str) -> int:
    return main(list(argv))


def load_grid(run_dir: Path) -> dict:
    with np.load(run_dir / "grid.npz") as z:
        return {k: z[k] for k in z.files}


def cli(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pdcov.cli", *argv], capture_output=True,
                          text=True, timeout=120)


def assert_clean_failure(proc: subprocess.CompletedProcess, *words: str) -> None:
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    for w in words:
        assert w in proc.stderr, proc.stderr


def survey_poses_csv(cfg: Path, tlog: Path, out: Path, t0_s: float, t1_s: float) -> Path:
    """The poses ``pdcov evaluate --log`` finds in a simulated flight's ``tlog`` between
    ``t0_s`` and ``t1_s`` (boot seconds: what a plan's prediction flies), as a pose CSV in
    ``out`` (with the whole flight's evaluation in out/all)."""
    assert run("evaluate", "--config", str(cfg), "--log", str(tlog), "--out",
               str(out / "all"), "--export-poses", str(out / "poses.csv"),
               "--no-progress") == 0
    header = (out / "poses.csv").read_text().splitlines()[0].split(",")[:8]
    poses = np.loadtxt(out / "poses.csv", delimiter=",", skiprows=1, usecols=range(8))
    survey = poses[(poses[:, 0] >= t0_s) & (poses[:, 0] <= t1_s)]
    np.savetxt(out / "survey.csv", survey, delimiter=",", header=",".join(header),
               comments="", fmt="%.10g")
    return out / "survey.csv"
