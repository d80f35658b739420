"""Bad command-line values and output paths are one-line errors (exit 2) found before any
work is done: shared argparse types (commands/args.py) and output checks (atomic.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from pdcov import cli
from pdcov.config.load import load_mission
from pdcov.errors import ConfigError, DomainError
from pdcov.planning.scenario import check_plan_size, scenario_of
from tests.support.cli_inputs import DEMO, evaluate, usage_error


def test_out_is_a_file_or_under_one(tmp_path: Path, poses: Path, capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("mine")
    assert "is a file" in usage_error(evaluate(str(blocker), poses), capsys)
    assert "is a file" in usage_error(evaluate(str(blocker / "run"), poses), capsys)
    assert blocker.read_text() == "mine"


def test_out_folder_of_the_users_files_is_not_replaced(tmp_path: Path, poses: Path,
                                                        capsys) -> None:
    mine = tmp_path / "documents"
    mine.mkdir()
    (mine / "thesis.tex").write_text("x")
    assert "files pdcov did not write" in usage_error(evaluate(str(mine), poses), capsys)


def test_output_files_in_missing_folders(tmp_path: Path, poses: Path, capsys) -> None:
    missing = tmp_path / "nope"
    err = usage_error(evaluate(str(tmp_path / "run"), poses, "--export-poses",
                               str(missing / "p.csv")), capsys)
    assert "--export-poses" in err and "does not exist" in err
    run = tmp_path / "run"
    assert not run.exists()
    assert "does not exist" in usage_error(
        ["footprint", "--config", str(DEMO), "--altitude-m", "10", "--out",
         str(missing / "f.png")], capsys)
    assert "is a folder" in usage_error(["compare", str(tmp_path), "--out", str(tmp_path)],
                                        capsys)
    assert "does not exist" in usage_error(
        ["detector", "plot", str(DEMO), "--out", str(missing / "d.png")], capsys)


@pytest.mark.parametrize("argv, option", [
    (["--altitude-m", "nan"], "--altitude-m"),
    (["--altitude-m", "inf"], "--altitude-m"),
    (["--altitude-m", "0"], "--altitude-m"),
    (["--altitude-m", "-10"], "--altitude-m"),
    (["--altitude-m", "10", "--speed-mps", "0"], "--speed-mps"),
    (["--altitude-m", "10", "--spacing-m", "-3"], "--spacing-m"),
    (["--altitude-m", "10", "--heading-deg", "nan"], "--heading-deg"),
    (["--altitude-m", "10", "--overlap", "1"], "--overlap"),
])
def test_numbers_are_checked_by_argparse(tmp_path: Path, capsys, argv: list[str],
                                         option: str) -> None:
    err = usage_error(["plan", "--config", str(DEMO), "--out", str(tmp_path / "p"), *argv],
                      capsys)
    assert f"argument {option}" in err
    assert not (tmp_path / "p").exists()


def test_other_commands_share_the_number_types(tmp_path: Path, capsys) -> None:
    assert "argument --altitude-m" in usage_error(
        ["footprint", "--config", str(DEMO), "--altitude-m", "-1"], capsys)
    assert "argument --target-pd" in usage_error(
        ["optimise", "--config", str(DEMO), "--target-pd", "1.5", "--out",
         str(tmp_path / "o")], capsys)
    assert "argument --speeds-mps" in usage_error(
        ["optimise", "--config", str(DEMO), "--target-pd", "0.8", "--speeds-mps", "3", "nan",
         "--out", str(tmp_path / "o")], capsys)


def test_upload_unknown_connection_scheme(tmp_path: Path, capsys) -> None:
    err = usage_error(["upload", str(tmp_path / "m.plan"), "--connect", "tpc:127.0.0.1:5760"],
                      capsys)
    assert "unknown connection 'tpc:127.0.0.1:5760'" in err and "udpin:" in err


@pytest.mark.parametrize("url", ["udpout:127.0.0.1:", "tcp:127.0.0.1", "udpin::14550",
                                 "tcp:127.0.0.1:99999", "udpout:127.0.0.1:port"])
def test_upload_connection_without_a_usable_port(tmp_path: Path, capsys, url: str) -> None:
    err = usage_error(["upload", str(tmp_path / "m.plan"), "--connect", url], capsys)
    assert ":HOST:PORT with a port in " in err and repr(url) in err


def test_huge_grid_is_refused_with_the_figure(tmp_path: Path, capsys) -> None:
    config = tmp_path / "m.yaml"
    config.write_text(DEMO.read_text().replace("cell_size_m: 1.0", "cell_size_m: 0.0001"))
    with pytest.raises(DomainError, match=r"160,000,000,000 cells; at most 4,294,967,296 cells"):
        load_mission(config).new_mission_grid()
    assert cli.main(["plan", "--config", str(config), "--altitude-m", "10", "--out",
                     str(tmp_path / "p")]) == 2
    assert "use cells of at least" in capsys.readouterr().err


def test_absurd_plans_refused_or_warned(capsys) -> None:
    sc = scenario_of(load_mission(DEMO))
    with pytest.raises(ConfigError, match=r"camera frames; at most 20,000,000"):
        check_plan_size(sc, 1e-6, 5.0)
    check_plan_size(sc, 0.01, 0.5)  # 160 km of track at 0.5 m/s: 89 h
    assert "WARNING" in capsys.readouterr().err
    check_plan_size(sc, 8.0, 5.0)
    assert capsys.readouterr().err == ""


def test_an_option_given_twice_is_refused(tmp_path: Path, poses: Path, capsys) -> None:
    """argparse keeps the last of two silently: `evaluate --log A --log B` evaluated B
    alone and exited 0, a map of one flight shown as the search's (--log now repeats:
    tests/slow/test_many_logs.py). Every command's single options refuse a second value,
    naming both, before any work."""
    err = usage_error([*evaluate(str(tmp_path / "run"), poses), "--poses", str(poses)],
                      capsys)
    assert "--poses: given twice" in err and str(poses) in err
    err = usage_error(["evaluate", "--config", str(DEMO), "--log", "a.tlog", "--out",
                       str(tmp_path / "run"), "--out", str(tmp_path / "other")], capsys)
    assert f"--out: given twice ({tmp_path / 'run'} and {tmp_path / 'other'})" in err
    assert not (tmp_path / "run").exists()


def test_plan_firmware_sets_the_qgc_firmware_type(tmp_path: Path, capsys) -> None:
    """No vehicle to ask: --firmware says which autopilot the .plan is for."""
    import json

    assert cli.main(["plan", "--config", str(DEMO), "--altitude-m", "10", "--no-figures",
                     "--firmware", "px4", "--out", str(tmp_path / "p")]) == 0
    doc = json.loads((tmp_path / "p" / "plan.plan").read_text())
    assert doc["mission"]["firmwareType"] == 12  # MAV_AUTOPILOT_PX4
    err = usage_error(["plan", "--config", str(DEMO), "--altitude-m", "10", "--firmware",
                       "apm", "--out", str(tmp_path / "q")], capsys)
    assert "--firmware" in err and "ardupilot" in err
