"""firmware_params/: the files parse, set what the daemon reads back on connect, say the same
thing in 4.5/4.6 and 4.7 naming, and the 4.7 file is accepted by the real ArduCopter firmware
(every value read back over MAVLink, the stream rates streamed on SERIAL2 unasked)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from pdcov.core.mount import GimbalMount
from pdcov.telemetry.gimbal import mount_param_names, resolve_interpretation
from tests.support.firmware_params import AP_47, PARAMS_DIR, read_parm

AP_46 = PARAMS_DIR / "ardupilot-4.5-4.6.parm"
PX4 = PARAMS_DIR / "px4.params"


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
