"""`pdcov evaluate` with coverage.looks: correlated: the run's grid is the core's (counts
saved beside the derived P_D, the snapshot reloads), and its summary names the rule."""

from __future__ import annotations

import numpy as np

from pdcov.config.load import load_mission
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_layer import Layer
from pdcov.core.looks import CorrelatedLooks
from tests.support import evaluate_inputs as inputs

DETECTOR = {"version": 4, "input_size_px": None, "bin_edges_px": [4, 16, 40, 100, 400],
            "p_detect": [0.2, 0.4, 0.5, 0.3], "p_false_alarm": [0.02, 0.03, 0.04, 0.05],
            "fa_rate_per_mpx": [0.05, 0.06, 0.08, 0.1],
            "looks": {"correlation": [0.4, 0.3, 0.3, 0.5]}}


def test_evaluate_with_correlated_looks(tmp_path, capsys):
    config = inputs.write_config(tmp_path, inputs.mission_doc(detector=DETECTOR,
                                                coverage={"looks": "correlated"}))
    poses = inputs.expected_poses(inputs.known_flight(), None)
    csv = inputs.write_pose_csv(tmp_path / "poses.csv", poses)
    assert inputs.run("evaluate", "--config", str(config), "--poses", str(csv), "--out",
               str(tmp_path / "run"), "--no-progress") == 0
    assert "looks: correlated (the detector model's per-person correlation" in \
        capsys.readouterr().out
    mission = load_mission(config)
    grid = mission.new_mission_grid()
    independent = CoverageGrid(grid.geometry, grid.mask, grid.camera, grid.detector)
    for p in poses:
        grid.update(p)
        independent.update(p)
    out = inputs.load_grid(tmp_path / "run")
    assert str(out["looks"]) == "correlated" and int(out["version"]) == 3
    assert isinstance(grid.looks_model, CorrelatedLooks)
    np.testing.assert_array_equal(out["looks_counts"], grid.read(Layer.LOOKS))
    np.testing.assert_array_equal(out["log_miss_d"], grid.log_miss_d)
    assert grid.n_obs.max() > 10
    # Many looks: the correlated P_D is below the independent one where cells were seen
    # more than once, equal where once.
    twice = grid.n_obs >= 2
    assert (grid.pd[twice] < independent.pd[twice] - 1e-6).mean() > 0.9
    (cam,) = mission.cameras
    again = CoverageGrid.load_npz(tmp_path / "run" / "grid.npz", cam.camera, cam.detector,
                                  looks=mission.looks)
    np.testing.assert_array_equal(again.pd, grid.pd)
