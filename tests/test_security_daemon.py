"""`pdcov serve` against a hostile or mistaken participant (issue 23, docs/reliability.md
"Security"): it answers MAVLink only to the autopilot's addresses, rate-limits snapshot
replies per requester, stamps its publications with its own Zenoh source, and resumes a
checkpoint only under the vehicle id that wrote it."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from serve_harness import serve_config

from benchmarks.harness import small_mission
from pdcov.core.pose import CameraPose
from pdcov.service.checkpoint import CHECKPOINT_NAME
from pdcov.service.daemon import Daemon
from pdcov.service.settings import load_serve_config

FIXED = {"type": "fixed", "roll_deg": 0, "pitch_deg": -90, "yaw_deg": 0}


def config(tmp: Path, vehicle_id: str, *, state: Path, zenoh_port: int = 7447,
           **service) -> Path:
    """A small fixed-mount mission for ``vehicle_id`` with its state in ``state``."""
    return serve_config(small_mission(vehicle_id=vehicle_id, mount=FIXED),
                        tmp / f"{vehicle_id}.yaml", zenoh_port=zenoh_port, state_dir=state,
                        **service)


# --- 4. a checkpoint resumes only under its own vehicle id -------------------------------------

def test_a_checkpoint_resumes_under_its_vehicle_id_only(tmp_path, caplog) -> None:
    state = tmp_path / "state"
    first = Daemon(load_serve_config(config(tmp_path, "uav1", state=state)))
    for k in range(3):
        first.live.grid.update(CameraPose(np.diag([1.0, -1.0, -1.0]),
                                          np.array([10.0 + 4 * k, 15.0, 12.0]), float(k)))
    first._checkpoint()
    saved = first.live.grid.frames
    assert saved == 3
    again = Daemon(load_serve_config(config(tmp_path, "uav1", state=state)))
    assert again.live.grid.frames == saved and again._checkpoint_info["resumed"]
    # The same mission flown as uav2 with the same state directory (a copied config):
    # uav1's frames must not be counted again under uav2.
    with caplog.at_level(logging.WARNING, logger="pdcov.serve"):
        other = Daemon(load_serve_config(config(tmp_path, "uav2", state=state)))
    assert other.live.grid.frames == 0 and not other.live.grid.n_obs.any()
    info = other._checkpoint_info
    assert not info["resumed"] and info["set_aside"] is not None
    aside = Path(info["set_aside"])
    assert aside.is_file() and not (state / CHECKPOINT_NAME).exists()
    line = caplog.records[-1].getMessage()
    assert "set aside" in line and "vehicle 'uav1'" in line, line
    # The file set aside is uav1's, whole: renamed back it resumes under uav1.
    aside.replace(state / CHECKPOINT_NAME)
    assert Daemon(load_serve_config(config(tmp_path, "uav1", state=state))
                  ).live.grid.frames == saved
