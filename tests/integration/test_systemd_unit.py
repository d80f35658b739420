"""systemd/pdcov.service and pdcov.sysusers: the directives docs/operations.md promises, and
systemd's own verdict (systemd-analyze verify / security --offline, systemd-sysusers --root)
when those tools are installed."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

SYSTEMD_DIR = Path(__file__).resolve().parents[2] / "systemd"
UNIT = SYSTEMD_DIR / "pdcov.service"
SYSUSERS = SYSTEMD_DIR / "pdcov.sysusers"
MAX_EXPOSURE = 2.0


def _analyzable_copy(tmp_path: Path) -> Path:
    """The unit with ExecStart pointing at an executable that exists here (verify checks it)."""
    text = UNIT.read_text().replace("/opt/pdcov/venv/bin/pdcov", sys.executable)
    copy = tmp_path / UNIT.name
    copy.write_text(text)
    return copy


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze absent")
def test_systemd_analyze_verify_is_clean(tmp_path) -> None:
    proc = subprocess.run(
        ["systemd-analyze", "verify", "--man=no", str(_analyzable_copy(tmp_path))],
        capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    # Unknown or misspelt directives are only warnings ("Unknown key ..., ignoring").
    assert proc.stderr.strip() == "", proc.stderr


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze absent")
def test_systemd_analyze_security_exposure_at_most_2(tmp_path) -> None:
    proc = subprocess.run(
        ["systemd-analyze", "security", "--offline=true", "--no-pager",
         str(_analyzable_copy(tmp_path))], capture_output=True, text=True, timeout=60)
    m = re.search(r"Overall exposure level for \S+: (\d+(?:\.\d+)?)", proc.stdout)
    assert m, proc.stdout + proc.stderr
    assert float(m.group(1)) <= MAX_EXPOSURE, proc.stdout


@pytest.mark.skipif(shutil.which("systemd-sysusers") is None, reason="systemd-sysusers absent")
def test_sysusers_creates_pdcov_in_dialout(tmp_path) -> None:
    etc = tmp_path / "etc"
    etc.mkdir()
    (etc / "passwd").write_text("root:x:0:0:root:/root:/bin/sh\n")
    (etc / "group").write_text("root:x:0:\ndialout:x:20:\n")
    proc = subprocess.run(["systemd-sysusers", f"--root={tmp_path}", str(SYSUSERS)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    users = {f[0]: f for f in (line.split(":") for line in (etc / "passwd").read_text()
                                .splitlines())}
    assert users["pdcov"][5] == "/var/lib/pdcov"
    assert int(users["pdcov"][2]) < 1000  # a system user
    members = {f[0]: f[3].split(",") for f in (line.split(":") for line in (etc / "group")
                                               .read_text().splitlines())}
    assert "pdcov" in members["dialout"]
    assert "pdcov" in members
