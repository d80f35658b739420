"""A run that cannot mean anything says so: a domain without a free cell is refused when the
config is read (evaluate, plan, optimise); a flight that never saw the domain is warned about
loudly (stderr, summary, metrics.json) with its distance from the domain; and "no camera
frame to evaluate" says why."""

from __future__ import annotations

import json

import numpy as np

from pdcov.core.pose import CameraPose
from tests.support.evaluate_inputs import (
    assert_clean_failure,
    cli,
    expected_poses,
    known_flight,
    mission_doc,
    write_config,
    write_pose_csv,
)

SQUARE = [[0, 0], [40, 0], [40, 40], [0, 40]]


def test_empty_domain_refused_by_evaluate_and_plan(tmp_path):
    config = write_config(tmp_path, mission_doc(domain={
        "polygon_enu_m": SQUARE, "obstacles_enu_m": [[[-1, -1], [41, -1], [41, 41],
                                                      [-1, 41]]]}))
    csv = write_pose_csv(tmp_path / "poses.csv", expected_poses(known_flight(), None)[:3])
    for argv in (["evaluate", "--poses", str(csv)], ["plan", "--altitude-m", "10"],
                 ["optimise", "--target-pd", "0.8"]):
        proc = cli(*argv, "--config", str(config), "--out", str(tmp_path / "run"))
        assert_clean_failure(proc, "mission.yaml: domain: no free cell to cover",
                             "obstacles cover the polygon")
    assert not (tmp_path / "run").exists()


def test_flight_that_never_sees_the_domain_warns_with_its_distance(tmp_path):
    config = write_config(tmp_path, mission_doc())
    far = [CameraPose(p.R_enu_cam, p.r_cam_enu + np.array([3000.0, 0.0, 0.0]), p.t_s)
           for p in expected_poses(known_flight(), None)]
    csv = write_pose_csv(tmp_path / "poses.csv", far)
    proc = cli("evaluate", "--config", str(config), "--poses", str(csv), "--out",
               str(tmp_path / "run"), "--no-progress")
    assert proc.returncode == 0, proc.stderr
    # The pass runs along x = 17..23 m, shifted 3 km east: 2977 m from x = 40.
    assert "WARNING: no frame observed any of the 1584 free cells" in proc.stderr
    assert "no closer than 2,977 m" in proc.stderr and "origin.lat_deg" in proc.stderr
    assert "WARNING: no frame observed" in proc.stdout
    doc = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert doc["cells_observed"] == 0
    assert len(doc["warnings"]) == 1 and "2,977 m" in doc["warnings"][0]


def test_flight_over_the_domain_has_no_warning(tmp_path):
    config = write_config(tmp_path, mission_doc())
    csv = write_pose_csv(tmp_path / "poses.csv", expected_poses(known_flight(), None))
    proc = cli("evaluate", "--config", str(config), "--poses", str(csv), "--out",
               str(tmp_path / "run"), "--no-progress")
    assert proc.returncode == 0 and "WARNING" not in proc.stderr + proc.stdout
    assert "warnings" not in json.loads((tmp_path / "run" / "metrics.json").read_text())


def test_no_frame_to_evaluate_says_why_and_keeps_the_summary(tmp_path):
    config = write_config(tmp_path, mission_doc())
    low = [CameraPose(p.R_enu_cam, p.r_cam_enu * np.array([1.0, 1.0, 0.0]) + [0, 0, 0.4],
                      p.t_s) for p in expected_poses(known_flight(), None)]
    csv = write_pose_csv(tmp_path / "poses.csv", low)
    proc = cli("evaluate", "--config", str(config), "--poses", str(csv), "--out",
               str(tmp_path / "run"))
    assert_clean_failure(proc, "no camera frame to evaluate: all 101 frames below "
                               "coverage.min_height_m = 1 m", "highest camera was 0.40 m")
    assert "poses: " in proc.stdout and "101 frames with the camera below" in proc.stdout
    assert not (tmp_path / "run").exists()
