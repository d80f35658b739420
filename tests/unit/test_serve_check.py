"""`pdcov serve --check` of the CMAC mission reports and exits."""

from __future__ import annotations

import yaml

from pdcov.bus.grid_state import MAX_CELLS, unseen_grid_warning
from pdcov.cli import main as pdcov_main
from pdcov.core.domain import GridGeometry
from tests.support.cmac_mission import CMAC


def test_check_reports_and_exits(tmp_path, capsys):
    cfg = tmp_path / "m.yaml"
    cfg.write_text(yaml.safe_dump({**CMAC, "service": {"state_dir": str(tmp_path / "s")}}))
    assert pdcov_main(["serve", "--config", str(cfg), "--check"]) == 0
    assert "ok" in capsys.readouterr().out
    cfg.write_text(yaml.safe_dump({**CMAC, "link": {"conect": ["tcp:x:1"]}}))
    assert pdcov_main(["serve", "--config", str(cfg), "--check"]) == 2
    assert "did you mean 'connect'" in capsys.readouterr().err
    cfg.write_text(yaml.safe_dump({**CMAC, "service": {"state_dir": "/proc/none"}}))
    assert pdcov_main(["serve", "--config", str(cfg), "--check"]) == 2
    assert "state_dir" in capsys.readouterr().err


def test_a_grid_no_ground_station_accepts_is_said_before_flight(tmp_path, capsys):
    """A grid over the watcher's MAX_CELLS is refused by every ground station: its vehicle
    would fly unseen. `--check` says so (still exit 0: the daemon computes and checkpoints
    it), and the rule is at the bound exactly."""
    side = MAX_CELLS ** 0.5
    assert unseen_grid_warning(GridGeometry(0.0, 0.0, 1.0, 4000, 4000)) is None
    assert unseen_grid_warning(GridGeometry(0.0, 0.0, 1.0, 4000, 4001)) is not None
    cfg = tmp_path / "m.yaml"
    cfg.write_text(yaml.safe_dump({
        **CMAC, "service": {"state_dir": str(tmp_path / "s")},
        "domain": {"polygon_enu_m": [[0, 0], [101, 0], [101, 101], [0, 101]],
                   "cell_size_m": 101 / (side + 2)}}))
    assert pdcov_main(["serve", "--config", str(cfg), "--check"]) == 0
    err = capsys.readouterr().err
    assert "WARNING" in err and f"more than the {MAX_CELLS:,} a ground station" in err
