"""`pdcov` reading the autopilot's parameters, as a process: no autopilot exits 2 with one
clear line."""

from __future__ import annotations

import subprocess
import sys

from tests.support.link_params_autopilot import gimbal_config


def test_no_autopilot_exits_2_with_one_clear_line(tmp_path):
    config = gimbal_config(tmp_path)
    proc = subprocess.run([sys.executable, "-m", "pdcov.cli", "mount-check", "--config",
                           str(config), "--connect", "udpin:127.0.0.1:0", "--timeout-s", "0.3"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and proc.stdout == ""
    assert proc.stderr.strip().count("\n") == 0
    assert "pdcov mount-check: error: no HEARTBEAT of an autopilot on 127.0.0.1:0 within 0.3 s" \
        in proc.stderr
