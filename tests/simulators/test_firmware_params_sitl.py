"""The ArduPilot 4.7 parameter file is accepted by the real firmware (ArduCopter SITL)."""

from __future__ import annotations

import time

import pytest

from pdcov.telemetry.link_params import read_params, wait_autopilot
from pdcov.telemetry.upload import mavlink2_connection
from tests.support.ardupilot_sitl import ardupilot_sitl, requires_ardupilot_sitl
from tests.support.firmware_params import AP_47, read_parm


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
