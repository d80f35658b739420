"""A tlog written by a fresh process keeps MAVLink 2 (pymavlink's MAVLINK20 is set before
its import)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from tests.support.mavlink_fixtures import write_tlog
from tests.support.telemetry_flights import gimbal_flight


def test_mavlink2_kept_in_a_fresh_process(tmp_path: Path) -> None:
    """pymavlink chooses the protocol from the process environment and the first magic byte
    it meets; pdcov's reading must depend on neither (the CLI imports pymavlink cold)."""
    path = write_tlog(tmp_path / "j.tlog", gimbal_flight(),
                      prefix=bytes(8) + b"\xfe\x05" + bytes(12))
    env = {k: v for k, v in os.environ.items() if k != "MAVLINK20"}
    code = ("import sys; from pdcov.telemetry.logs import read_flight_log; "
            "print(len(read_flight_log(sys.argv[1]).gimbal.t_s))")
    out = subprocess.run([sys.executable, "-c", code, str(path)], env=env, timeout=120,
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "50"
