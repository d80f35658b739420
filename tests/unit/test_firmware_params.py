"""firmware_params/: the files parse, set what the daemon reads back on connect, say the same
thing in 4.5/4.6 and 4.7 naming, and the 4.7 file is accepted by the real ArduCopter firmware
(every value read back over MAVLink, the stream rates streamed on SERIAL2 unasked)."""

from __future__ import annotations

import math
import re
import time
from pathlib import Path

import pytest
from ardupilot_sitl import ardupilot_sitl, requires_ardupilot_sitl

from pdcov.core.mount import GimbalMount
from pdcov.telemetry.gimbal import mount_param_names, resolve_interpretation
from pdcov.telemetry.link_params import read_params, wait_autopilot
from pdcov.telemetry.upload import mavlink2_connection

PARAMS_DIR = Path(__file__).resolve().parents[1] / "firmware_params"
AP_46 = PARAMS_DIR / "ardupilot-4.5-4.6.parm"
AP_47 = PARAMS_DIR / "ardupilot-4.7.parm"
PX4 = PARAMS_DIR / "px4.params"
AP_NAME = re.compile(r"^[A-Z][A-Z0-9_]{0,15}$")  # AP_MAX_NAME_SIZE 16


def read_parm(path: Path) -> dict[str, float]:
    """An ArduPilot .parm file (NAME VALUE per line, '#' comments), refusing duplicates."""
    out: dict[str, float] = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = line.replace(",", " ").split()
        assert len(fields) == 2, f"{path.name}:{n}: expected NAME VALUE, got {line!r}"
        name, value = fields
        assert AP_NAME.match(name), f"{path.name}:{n}: bad parameter name {name!r}"
        assert name not in out, f"{path.name}:{n}: {name} set twice"
        out[name] = float(value)
    return out


def read_qgc_params(path: Path) -> dict[str, float]:
    """A QGroundControl .params file: vehicle, component, name, value, type (tab-separated)."""
    out: dict[str, float] = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        fields = line.split("\t")
        assert len(fields) == 5, f"{path.name}:{n}: expected 5 tab-separated fields: {line!r}"
        sysid, compid, name, value, type_ = fields
        assert (int(sysid), int(compid)) == (1, 1), f"{path.name}:{n}"
        assert 1 <= len(name) <= 16 and name.isupper(), f"{path.name}:{n}: bad name {name!r}"
        assert type_ in ("6", "9"), f"{path.name}:{n}: type {type_} (6 INT32 or 9 REAL32)"
        if type_ == "6":
            int(value)  # an INT32 parameter must not be written as a float
        assert name not in out, f"{path.name}:{n}: {name} set twice"
        out[name] = float(value)
    return out


@pytest.mark.parametrize("path", [AP_46, AP_47], ids=lambda p: p.name)
def test_ardupilot_file_sets_every_mount_parameter_the_daemon_reads(path) -> None:
    params = read_parm(path)
    missing = [n for n in mount_param_names(1) if n not in params]
    assert not missing, f"{path.name} leaves unset: {missing}"
    assert params["SERIAL2_PROTOCOL"] == 2  # MAVLink 2
    assert params["SERIAL2_BAUD"] == 921
    # What `attitude_frame: auto` makes of these parameters live: a servo mount -> body.
    mount = GimbalMount.from_config({"type": "gimbal", "attitude_frame": "auto"})
    interp = resolve_interpretation(mount, params, "the autopilot")
    assert interp.frame == "body", interp.reason
    assert interp.limits_rad[1].tolist() == pytest.approx([-math.pi / 2, 0.0])


def test_46_and_47_files_agree_under_the_renaming() -> None:
    """4.7 renamed SRn_X to MAV(n+1)_X (GCS.cpp: MAVn is channel n-1) and SYSID_MYGCS to
    MAV_GCS_SYSID; everything else is the same."""
    old, new = read_parm(AP_46), read_parm(AP_47)
    renamed = {re.sub(r"^SR(\d)_", lambda m: f"MAV{int(m.group(1)) + 1}_", k): v
               for k, v in old.items()}
    renamed["MAV_GCS_SYSID"] = renamed.pop("SYSID_MYGCS")
    assert renamed == new
    assert not any(k.startswith("SR") for k in new)


def test_px4_file_parses_and_sets_the_companion_link_and_gimbal() -> None:
    p = read_qgc_params(PX4)
    assert p["MAV_1_CONFIG"] == 102  # TELEM 2
    assert p["MAV_1_MODE"] == 2  # Onboard
    assert p["SER_TEL2_BAUD"] == 921600
    assert p["MAV_PROTO_VER"] == 2
    assert p["MNT_MODE_OUT"] == 2  # MAVLink gimbal protocol v2


def _rate_hz(msgs: list) -> float:
    """Messages per second of autopilot boot time (time_boot_ms), so --speedup cancels."""
    t_ms = sorted({m.time_boot_ms for m in msgs})
    return (len(t_ms) - 1) * 1000.0 / (t_ms[-1] - t_ms[0]) if len(t_ms) > 2 else 0.0


@requires_ardupilot_sitl
def test_47_file_is_accepted_by_the_real_firmware(tmp_path) -> None:
    wanted = read_parm(AP_47)
    t0 = time.monotonic()
    with ardupilot_sitl(tmp_path / "sitl", [AP_47], speedup=5) as sitl:
        gcs = mavlink2_connection(sitl.serial_url(0), 255, 190)
        try:
            sysid, compid = wait_autopilot(gcs, 30.0)
            got = read_params(gcs, wanted, target_system=sysid, target_component=compid,
                              timeout_s=15.0)
        finally:
            gcs.close()
        missing = sorted(set(wanted) - set(got))
        assert not missing, f"the firmware does not know {missing}"
        for name, value in wanted.items():
            assert got[name] == pytest.approx(value), name

        # SERIAL2 streams what MAV3_* asks for without any request from us: MAV3 is SERIAL2.
        companion = mavlink2_connection(sitl.serial_url(2), sysid, 191)
        try:
            seen: dict[str, list] = {"ATTITUDE": [], "GLOBAL_POSITION_INT": [],
                                     "GIMBAL_DEVICE_ATTITUDE_STATUS": []}
            t_end = time.monotonic() + 20.0
            while time.monotonic() < t_end and min(len(v) for v in seen.values()) < 40:
                msg = companion.recv_match(type=list(seen), blocking=True, timeout=1.0)
                if msg is not None:
                    seen[msg.get_type()].append(msg)
        finally:
            companion.close()
    assert time.monotonic() - t0 < 60.0
    rates = {k: _rate_hz(v) for k, v in seen.items()}
    # ArduPilot's scheduler spreads a stream's messages over its slots; allow 30 % below.
    assert rates["ATTITUDE"] >= 0.7 * wanted["MAV3_EXTRA1"], rates
    assert rates["GLOBAL_POSITION_INT"] >= 0.7 * wanted["MAV3_POSITION"], rates
    assert rates["GIMBAL_DEVICE_ATTITUDE_STATUS"] >= 0.7 * wanted["MAV3_EXTRA3"], rates
    assert all(m.get_srcComponent() == 1 for m in seen["GIMBAL_DEVICE_ATTITUDE_STATUS"])
