"""Output folders across real runs: evaluate without a prior drops the posterior and says so,
and a real kill -9 mid-run is recovered by the next run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pdcov import cli
from pdcov.atomic import replacing_dir
from tests.support.output_runs import mode, previous_run, snapshot

DEMO = Path(__file__).resolve().parents[2] / "service" / "pdcov" / "data" / "demo_mission.yaml"
POSES = "t_s,x_m,y_m,z_m,qw,qx,qy,qz\n0.0,-40.0,-40.0,10.0,0.0,1.0,0.0,0.0\n"


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


KILLED_RUN = """
import sys, time
from pathlib import Path
from pdcov.atomic import replacing_dir, write_text_atomic
out = Path(sys.argv[1])
with replacing_dir(out):
    write_text_atomic(out / "metrics.json", '{"frames": 1')
    print("writing", flush=True)
    time.sleep(60)
"""


def test_a_real_kill_9_mid_run_is_recovered_by_the_next_run(tmp_path: Path) -> None:
    out = tmp_path / "run"
    before = previous_run(out)
    child = subprocess.Popen([sys.executable, "-c", KILLED_RUN, str(out)],
                             stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None and child.stdout.readline() == "writing\n"
        child.kill()
        child.wait(timeout=10)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait(timeout=10)
    assert len(list(tmp_path.glob(".run.*.pdcov-old"))) == 1  # the state to recover from
    assert snapshot(out) != before
    with pytest.raises(KeyboardInterrupt), replacing_dir(out):
        raise KeyboardInterrupt
    assert snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
