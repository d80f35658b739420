"""The systemd unit's promised directives and its example config passing `serve --check`
(tests/integration/test_systemd_unit.py: systemd-analyze)."""

from __future__ import annotations

from pathlib import Path

from pdcov.bus.session import session_mode
from pdcov.cli import main as pdcov_main
from pdcov.service.settings import load_serve_config

SYSTEMD_DIR = Path(__file__).resolve().parents[2] / "systemd"
UNIT = SYSTEMD_DIR / "pdcov.service"
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


def test_example_config_loads_and_passes_serve_check(tmp_path, capsys) -> None:
    cfg = load_serve_config(SYSTEMD_DIR / "pdcov.yaml")
    assert cfg.mission.new_mission_grid().mask.sum() > 0
    assert cfg.mission.first_camera.mount.attitude_frame == "auto"
    # auto, listening: a peer the ground station reaches; without listen, a router's client
    assert cfg.bus.mode == "auto" and session_mode(cfg.bus) == "peer"
    assert not cfg.bus.multicast_scouting
    assert cfg.link.connect[0].startswith("serial:/dev/serial0:")
    # The unit's --state-dir %S/pdcov is the state_dir the config names.
    assert cfg.service.state_dir == "/var/lib/pdcov"
    assert pdcov_main(["serve", "--config", str(SYSTEMD_DIR / "pdcov.yaml"), "--state-dir",
                       str(tmp_path / "state"), "--check"]) == 0
    assert "ok" in capsys.readouterr().out
