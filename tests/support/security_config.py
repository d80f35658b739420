"""The small fixed-mount mission of the security tests, per vehicle id and state folder."""

from __future__ import annotations

from pathlib import Path

from tests.support.harness import small_mission
from tests.support.serve_harness import serve_config

FIXED = {"type": "fixed", "roll_deg": 0, "pitch_deg": -90, "yaw_deg": 0}


def config(tmp: Path, vehicle_id: str, *, state: Path, zenoh_port: int = 7447,
           **service) -> Path:
    """A small fixed-mount mission for ``vehicle_id`` with its state in ``state``."""
    return serve_config(small_mission(vehicle_id=vehicle_id, mount=FIXED),
                        tmp / f"{vehicle_id}.yaml", zenoh_port=zenoh_port, state_dir=state,
                        **service)
