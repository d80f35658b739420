"""Outputs: files get the normal mode under the umask; a run folder is replaced whole or not
at all (atomic.replacing_dir), so an interrupted run leaves the previous one intact and no
file of an earlier run stays beside a new one."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pytest

from pdcov import cli
from pdcov.atomic import MARKER, atomic_path, replacing_dir, write_text_atomic

DEMO = Path(__file__).resolve().parents[1] / "service" / "pdcov" / "data" / "demo_mission.yaml"
POSES = "t_s,x_m,y_m,z_m,qw,qx,qy,qz\n0.0,-40.0,-40.0,10.0,0.0,1.0,0.0,0.0\n"


@pytest.fixture
def umask():
    old = os.umask(0o022)
    yield lambda m: os.umask(m)
    os.umask(old)


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_files_get_the_mode_of_a_new_file(tmp_path: Path, umask) -> None:
    write_text_atomic(tmp_path / "a.json", "{}")
    with atomic_path(tmp_path / "b.bin") as tmp:
        tmp.write_bytes(b"x")
    assert mode(tmp_path / "a.json") == 0o644 and mode(tmp_path / "b.bin") == 0o644
    umask(0o027)
    write_text_atomic(tmp_path / "c.json", "{}")
    assert mode(tmp_path / "c.json") == 0o640


def previous_run(out: Path) -> dict[str, bytes]:
    with replacing_dir(out):
        write_text_atomic(out / "metrics.json", '{"frames": 495}')
        write_text_atomic(out / "heatmap.png", "495 frames")
    return snapshot(out)


def snapshot(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.iterdir())}


@pytest.mark.parametrize("interrupt", [KeyboardInterrupt, RuntimeError])
def test_interrupted_run_leaves_the_previous_one_intact(tmp_path: Path, interrupt) -> None:
    out = tmp_path / "run"
    before = previous_run(out)
    assert set(before) == {MARKER, "metrics.json", "heatmap.png"}
    with pytest.raises(interrupt), replacing_dir(out):
        write_text_atomic(out / "metrics.json", '{"frames": 186}')  # half of the new run
        raise interrupt("Ctrl-C mid-write")
    assert snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # nothing left beside


def test_new_run_replaces_the_old_whole(tmp_path: Path) -> None:
    out = tmp_path / "run"
    previous_run(out)
    (out / "posterior.npy").write_bytes(b"an earlier --prior run")
    with replacing_dir(out) as replaced:
        write_text_atomic(out / "metrics.json", '{"frames": 186}')
    assert replaced
    assert set(snapshot(out)) == {MARKER, "metrics.json"}


def test_evaluate_without_prior_drops_posterior_and_says_so(tmp_path: Path, umask,
                                                            capsys) -> None:
    poses = tmp_path / "poses.csv"
    poses.write_text(POSES)
    prior = tmp_path / "prior.npy"
    np.save(prior, np.full((40, 40), 1 / 1600))
    out = tmp_path / "run"
    argv = ["evaluate", "--config", str(DEMO), "--poses", str(poses), "--out", str(out),
            "--no-progress"]
    assert cli.main([*argv, "--prior", str(prior)]) == 0
    assert (out / "posterior.npy").exists()
    assert cli.main(argv) == 0
    assert not (out / "posterior.npy").exists() and not (out / "posterior.tif").exists()
    assert f"replaced the previous outputs in {out}" in capsys.readouterr().out
    assert {mode(p) for p in out.iterdir()} == {0o644}
