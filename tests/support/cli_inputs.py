"""A pose CSV and `pdcov evaluate`'s argument list over the demo mission, and argparse's usage
error, for the tests of the command line's inputs."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from pdcov import cli

DEMO = Path(__file__).resolve().parents[2] / "service" / "pdcov" / "data" / "demo_mission.yaml"
POSES = "t_s,x_m,y_m,z_m,qw,qx,qy,qz\n0.0,-40.0,-40.0,10.0,0.0,1.0,0.0,0.0\n"


def usage_error(argv: list[str], capsys) -> str:
    """argparse's usage error: exit 2, one message, no traceback."""
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "error:" in err
    return err


@pytest.fixture
def poses(tmp_path: Path) -> Path:
    path = tmp_path / "poses.csv"
    path.write_text(POSES)
    return path


def evaluate(out: str, poses: Path, *extra: str) -> list[str]:
    return ["evaluate", "--config", str(DEMO), "--poses", str(poses), "--out", out, *extra]


def mount_tmpfs(where: Path, options: str) -> None:
    where.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)],
                          capture_output=True, timeout=10)
    if done.returncode != 0:
        pytest.skip("cannot mount a tmpfs here (needs root)")
