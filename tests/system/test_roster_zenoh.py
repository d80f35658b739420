"""The fleet roster over real Zenoh: `pdcov watch --config` with fleet.vehicles [uav1]
beside a rogue session publishing status and tiles as an invented uav9 (docs/ground-station.md
"Fleet roster")."""

from __future__ import annotations

import time
from pathlib import Path

import yaml

from tests.support.watch_fixtures import (
    DEMO,
    TinyPublisher,
    ZenohTinyDaemon,
    start_watcher,
    stop_watcher,
)


def test_a_rogue_vehicle_not_on_the_roster_changes_no_figure_nor_export(
        router, processes, daemons, tmp_path):
    doc = yaml.safe_load(Path(DEMO).read_text())
    doc["fleet"] = {"vehicles": ["uav1", "uav2"]}
    cfg = tmp_path / "mission.yaml"
    cfg.write_text(yaml.safe_dump(doc))
    real = ZenohTinyDaemon(TinyPublisher("uav1"), router)
    rogue = ZenohTinyDaemon(TinyPublisher("uav9", y_m=-20.0), router)
    daemons += [real, rogue]
    w = start_watcher(processes, router, "--config", cfg, "--record", tmp_path / "rec")
    for _ in range(20):
        real.publish_step()
        rogue.publish_step(3)
        time.sleep(0.05)
    time.sleep(1.0)
    out = stop_watcher(w)
    share = real.pub.grid.metrics([0.8]).proportion_at_or_above[0.8]
    assert f"coverage {100 * share:.1f}% of free cells at P_D >= 0.8" in out, out
    assert "(1 vehicle: uav1)" in out, out
    assert "unknown vehicle uav9: not on fleet.vehicles" in out, out
    assert not (tmp_path / "rec" / "uav9").exists()
    exports = sorted((tmp_path / "rec" / "exports").iterdir())
    assert exports
    assert not [f.name for f in exports if b"uav9" in f.read_bytes()]
