"""User text files: a UTF-8 BOM is accepted, a byte that is not UTF-8 is one clear error."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pdcov import cli
from pdcov.config.load import load_mission
from pdcov.errors import ConfigError, InputFileError
from pdcov.planning.plan_files import read_mission
from pdcov.telemetry.pose_csv import read_pose_csv

DEMO = Path(__file__).resolve().parents[2] / "service" / "pdcov" / "data" / "demo_mission.yaml"
POSES = "t_s,x_m,y_m,z_m,qw,qx,qy,qz\n0.0,1.0,2.0,10.0,0.0,1.0,0.0,0.0\n" \
        "0.2,1.5,2.0,10.0,0.0,1.0,0.0,0.0\n"


def test_pose_csv_with_a_bom_is_read(tmp_path: Path) -> None:
    path = tmp_path / "poses.csv"
    path.write_bytes(b"\xef\xbb\xbf" + POSES.replace("\n", "\r\n").encode())
    poses = read_pose_csv(path)
    assert len(poses) == 2
    np.testing.assert_allclose(poses[1].r_cam_enu, [1.5, 2.0, 10.0])


def test_pose_csv_not_utf8_names_line_and_offset(tmp_path: Path) -> None:
    path = tmp_path / "poses.csv"
    path.write_bytes(POSES.encode() + b"# caf\xe9\n")
    with pytest.raises(InputFileError, match=r"poses.csv:4: byte 0xe9 at byte offset \d+ is not"):
        read_pose_csv(path)


def latin1_config(tmp_path: Path) -> Path:
    text = DEMO.read_text()
    path = tmp_path / "mission.yaml"
    path.write_bytes(b"# relev\xe9 par l'\xe9quipe\n" + text.encode())
    return path


def test_yaml_not_utf8_is_one_clear_error(tmp_path: Path) -> None:
    path = latin1_config(tmp_path)
    with pytest.raises(ConfigError) as exc:
        load_mission(path)
    assert f"{path}:1: byte 0xe9 at byte offset 7 is not UTF-8" in str(exc.value)


def test_yaml_with_a_bom_is_read(tmp_path: Path) -> None:
    path = tmp_path / "mission.yaml"
    path.write_bytes(b"\xef\xbb\xbf" + DEMO.read_bytes())
    assert load_mission(path).cameras


def test_cli_exits_2_without_traceback(tmp_path: Path, capsys) -> None:
    path = latin1_config(tmp_path)
    poses = tmp_path / "poses.csv"
    poses.write_text(POSES)
    out = tmp_path / "run"
    assert cli.main(["evaluate", "--config", str(path), "--poses", str(poses),
                     "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "not UTF-8" in err and "Traceback" not in err
    assert not out.exists()


def test_plan_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "m.waypoints"
    path.write_bytes(b"QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t-35.3\t149.1\t584\t1 \xff\n")
    with pytest.raises(InputFileError, match="m.waypoints:2: byte 0xff"):
        read_mission(path)
