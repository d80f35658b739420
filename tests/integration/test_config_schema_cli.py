"""The command line refuses a misspelt config key with exit 2 and writes nothing."""

from __future__ import annotations

from pdcov.config.load import load_mission
from tests.support.config_docs import renamed
from tests.support.evaluate_inputs import (
    assert_clean_failure,
    cli,
    expected_poses,
    known_flight,
    mission_doc,
    write_config,
    write_pose_csv,
)


def test_cli_refuses_a_misspelt_key_with_exit_2_and_writes_nothing(tmp_path):
    config = write_config(tmp_path, renamed(mission_doc(), "domain.obstacles_enu_m",
                                            "obstacle_enu_m"))
    csv = write_pose_csv(tmp_path / "poses.csv", expected_poses(known_flight(), None)[:3])
    proc = cli("evaluate", "--config", str(config), "--poses", str(csv), "--out",
               str(tmp_path / "run"))
    assert_clean_failure(proc, "mission.yaml: domain.obstacle_enu_m: unknown key",
                         "did you mean 'obstacles_enu_m'?")
    assert not (tmp_path / "run").exists()
    assert load_mission(write_config(tmp_path, mission_doc(), "ok.yaml")).cell_size_m == 1.0
