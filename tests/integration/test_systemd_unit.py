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

from pdcov.bus.session import session_mode
from pdcov.cli import main as pdcov_main
from pdcov.service.settings import load_serve_config

SYSTEMD_DIR = Path(__file__).resolve().parents[1] / "systemd"
UNIT = SYSTEMD_DIR / "pdcov.service"
SYSUSERS = SYSTEMD_DIR / "pdcov.sysusers"
MAX_EXPOSURE = 2.0

REQUIRED = {
    "Type": "notify",
    "Restart": "on-failure",
    "User": "pdcov",
    "SupplementaryGroups": "dialout",
    "StateDirectory": "pdcov",
    "NoNewPrivileges": "yes",
    "ProtectSystem": "strict",
    "ProtectHome": "yes",
    "PrivateTmp": "yes",
    "CapabilityBoundingSet": "",
    "RestrictAddressFamilies": "AF_UNIX AF_INET AF_INET6 AF_NETLINK",
    "MemoryDenyWriteExecute": "yes",
    "DevicePolicy": "closed",
    "SystemCallArchitectures": "native",
}


def unit_directives(text: str) -> dict[str, list[str]]:
    """Section-less key -> values (a key may repeat, as DeviceAllow does)."""
    out: dict[str, list[str]] = {}
    for line in text.splitlines():
        line = line.strip()
        if not line or line[0] in "#;[":
            continue
        key, sep, value = line.partition("=")
        assert sep, f"{UNIT}: not KEY=VALUE: {line!r}"
        out.setdefault(key.strip(), []).append(value.strip())
    return out


def test_unit_has_the_promised_directives() -> None:
    d = unit_directives(UNIT.read_text())
    for key, value in REQUIRED.items():
        assert value in d.get(key, []), f"{key}={value} missing from {UNIT.name}"
    assert float(d["WatchdogSec"][0].removesuffix("s")) > 0
    assert d["ExecStart"][0].split()[1:3] == ["serve", "--config"]
    assert "--state-dir %S/pdcov" in d["ExecStart"][0]  # %S/pdcov is StateDirectory=pdcov
    assert "@system-service" in d["SystemCallFilter"]
    devices = {v.split()[0] for v in d["DeviceAllow"]}
    assert {"char-ttyAMA", "char-ttyS", "char-ttyUSB", "char-ttyACM"} <= devices


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


def test_example_config_loads_and_passes_serve_check(tmp_path, capsys) -> None:
    cfg = load_serve_config(SYSTEMD_DIR / "pdcov.yaml")
    assert cfg.mission.new_grid().mask.sum() > 0
    assert cfg.mission.mount.attitude_frame == "auto"
    # auto, listening: a peer the ground station reaches; without listen, a router's client
    assert cfg.bus.mode == "auto" and session_mode(cfg.bus) == "peer"
    assert not cfg.bus.multicast_scouting
    assert cfg.link.connect[0].startswith("serial:/dev/serial0:")
    # The unit's --state-dir %S/pdcov is the state_dir the config names.
    assert cfg.service.state_dir == "/var/lib/pdcov"
    assert pdcov_main(["serve", "--config", str(SYSTEMD_DIR / "pdcov.yaml"), "--state-dir",
                       str(tmp_path / "state"), "--check"]) == 0
    assert "ok" in capsys.readouterr().out
