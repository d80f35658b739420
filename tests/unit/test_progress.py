"""Long planning shows progress even when stderr is not a terminal: plain lines."""

from __future__ import annotations

from pathlib import Path

from pdcov import cli
from pdcov.planning.progress import progress

DEMO = Path(__file__).resolve().parents[2] / "service" / "pdcov" / "data" / "demo_mission.yaml"


def test_lines_not_redraws_off_a_terminal(capsys) -> None:
    assert list(progress(range(5), desc="frames", unit="frame", every_s=0.0)) == list(range(5))
    err = capsys.readouterr().err
    assert "\r" not in err
    lines = err.splitlines()
    assert len(lines) >= 2 and all(line.startswith("frames:") for line in lines)
    assert "5/5" in lines[-1]


def test_disabled_is_silent(capsys) -> None:
    assert list(progress(range(3), desc="x", unit="x", enabled=False)) == [0, 1, 2]
    assert capsys.readouterr().err == ""


def test_plan_reports_progress_to_a_pipe(tmp_path: Path, capsys) -> None:
    assert cli.main(["plan", "--config", str(DEMO), "--altitude-m", "12", "--out",
                     str(tmp_path / "p"), "--no-figures"]) == 0
    err = capsys.readouterr().err
    assert "frames:" in err and "\r" not in err


def test_evaluate_says_which_files_it_is_writing(tmp_path: Path, capsys) -> None:
    poses = DEMO.parents[3] / "tests" / "data" / "poses_nadir_10m.csv"
    assert cli.main(["evaluate", "--config", str(DEMO), "--poses", str(poses), "--out",
                     str(tmp_path / "run")]) == 0
    err = capsys.readouterr().err
    stages = [line for line in err.splitlines() if line.startswith("writing ")]
    assert [s.split(" in ")[0] for s in stages] == [
        "writing metrics.json and grid.npz", "writing the GeoTIFFs and outline.geojson",
        "writing the exports", "writing the figures"]
