"""`pdcov evaluate --dask`: the logs evaluated on a real Dask cluster (a LocalCluster of two
worker processes on 127.0.0.1) give the map of the local merge bit for bit; a scheduler
that does not answer is a clear error."""

from __future__ import annotations

import pytest

from tests.support.evaluate_inputs import assert_clean_failure, cli, mission_doc, write_config
from tests.support.sortie_logs import assert_same_map, one_by_one, write_sorties

distributed = pytest.importorskip("distributed")


def test_logs_on_a_dask_cluster_equal_the_local_merge(tmp_path):
    config = write_config(tmp_path, mission_doc())
    logs = write_sorties(tmp_path / "logs", 3)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, host="127.0.0.1",
                                  dashboard_address=None, processes=True) as cluster:
        proc = cli("evaluate", "--config", str(config), "--log", str(tmp_path / "logs"),
                   "--out", str(tmp_path / "dask"), "--dask", cluster.scheduler_address,
                   "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert f"on the Dask cluster at {cluster.scheduler_address}" in proc.stdout
    assert_same_map(tmp_path / "dask", one_by_one(config, logs, tmp_path))


def test_an_unreachable_scheduler_is_named(tmp_path):
    config = write_config(tmp_path, mission_doc())
    logs = write_sorties(tmp_path / "logs", 2)
    proc = cli("evaluate", "--config", str(config), "--log", str(logs[0]), "--log",
               str(logs[1]), "--out", str(tmp_path / "run"), "--dask", "tcp://127.0.0.1:9")
    assert_clean_failure(proc, "--dask tcp://127.0.0.1:9: cannot reach the Dask scheduler")
    assert not (tmp_path / "run").exists()
