"""`pdcov serve --check` of the CMAC mission reports and exits."""

from __future__ import annotations

import yaml

from pdcov.cli import main as pdcov_main
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
