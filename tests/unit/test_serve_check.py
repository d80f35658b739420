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


def test_check_makes_and_changes_nothing_on_disk(tmp_path, capsys):
    cfg = tmp_path / "m.yaml"
    missing = tmp_path / "var" / "lib" / "pdcov"
    cfg.write_text(yaml.safe_dump({**CMAC, "service": {"state_dir": str(missing)}}))
    before = sorted(tmp_path.rglob("*"))
    assert pdcov_main(["serve", "--config", str(cfg), "--check"]) == 0
    out, err = capsys.readouterr()
    assert "ok" in out
    assert f"WARNING: service.state_dir {missing} does not exist: the daemon makes it at " \
           "start (--check makes nothing)" in err
    assert sorted(tmp_path.rglob("*")) == before
    assert pdcov_main(["serve", "--config", str(cfg), "--check", "--state-dir",
                       str(cfg / "state")]) == 2
    assert f"service.state_dir {cfg / 'state'}: cannot be made: {cfg} is not a folder" \
        in capsys.readouterr().err
    assert pdcov_main(["serve", "--config", str(cfg), "--check", "--state-dir", str(cfg)]) == 2
    assert f"service.state_dir {cfg}: not a folder" in capsys.readouterr().err
    assert sorted(tmp_path.rglob("*")) == before
