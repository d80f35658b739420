"""The GNSS accuracy the autopilot reports, per frame (telemetry/gnss_accuracy.py): the
adapters (GPS_RAW_INT h_acc/v_acc, DataFlash GPA, ULog vehicle_gps_position), the rule in
force at a frame by hand, the daemon's detections geolocated with it (smaller sigma_m with a
smaller reported accuracy) equal to ``pdcov evaluate`` of its recording (the tlog path), the
status, and the real ArduPilot logs."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.bus.detections import decode_detections
from pdcov.bus.frames import encode_frames_v2
from pdcov.bus.status import decode_status, encode_status
from pdcov.cli import main as pdcov_main
from pdcov.core.detections import Box, FrameBoxes
from pdcov.core.geodesy import Origin, geodetic_to_enu
from pdcov.core.geolocate import PositionAccuracy
from pdcov.service.detections import DETECTIONS_PERIOD_S
from pdcov.service.link_setup import LinkReport
from pdcov.telemetry.adapters import sample_from_mavlink, samples_from_dataflash
from pdcov.telemetry.gnss_accuracy import (
    GNSS_ACCURACY_HOLD_S,
    accuracy_at,
    merge_accuracy,
    position_accuracies,
)
from pdcov.telemetry.logs import read_flight_log
from pdcov.telemetry.samples import GnssAccuracySample
from pdcov.telemetry.series import GnssAccuracySeries
from tests.support.detections_driver import Driver
from tests.support.link_feed import FIXED, MISSION, Hover, pack, without_epoch


def _in_force(sample: GnssAccuracySample) -> PositionAccuracy | None:
    """The accuracy a frame 1 s after ``sample`` (its only report) is geolocated with."""
    series = GnssAccuracySeries.from_samples([sample])
    return position_accuracies(*accuracy_at(series, np.array([sample.t_s + 1.0])))[0]


REAL = Path(__file__).resolve().parents[2].parent / "shared" / "real-logs"
UINT32_MAX = 2**32 - 1


def _gps_raw_int(h_acc: int, v_acc: int, fix_type: int = 3, *, mavlink1: bool = False
                 ) -> GnssAccuracySample:
    """The sample of a GPS_RAW_INT with these fields, through pymavlink's encoder and
    parser (MAVLink 1: a MAVLink 1 frame of the dialect before the extensions)."""
    fields = (0, fix_type, 473977420, 85455940, 500_000, 70, 110, 0, 65535, 14)
    if mavlink1:
        from pymavlink.dialects.v10 import ardupilotmega as mavlink_v1

        mav = mavlink_v1.MAVLink(None, srcSystem=1, srcComponent=1)
        data = bytes(mav.gps_raw_int_encode(*fields).pack(mav))
    else:
        mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        data = bytes(mav.gps_raw_int_encode(*fields, 0, h_acc, v_acc, 0, 0, 0).pack(mav))
    decoded = mavlink.MAVLink(None).parse_buffer(data)
    assert decoded is not None and decoded[0].get_type() == "GPS_RAW_INT"
    sample = sample_from_mavlink(decoded[0], 7.0)
    assert isinstance(sample, GnssAccuracySample) and sample.t_s == 7.0
    return sample


def test_gps_raw_int_h_acc_v_acc_in_mm_become_metres() -> None:
    assert _gps_raw_int(250, 400) == GnssAccuracySample(7.0, 0.25, 0.4)
    assert _in_force(_gps_raw_int(250, 400)) == PositionAccuracy(0.25, 0.4)
    assert _in_force(_gps_raw_int(1_000_000, 1)) == PositionAccuracy(1000.0, 0.001)


@pytest.mark.parametrize(("h_acc", "v_acc", "fix_type", "mavlink1"), [
    (0, 400, 3, False),             # 0: the receiver reports none
    (250, 0, 3, False),             # either unknown: unknown
    (UINT32_MAX, 400, 3, False),    # 4295 km: no accuracy
    (1_000_001, 400, 3, False),     # beyond MAX_GNSS_ACCURACY_M
    (250, 400, 2, False),           # a 2D fix
    (250, 400, 1, False),           # no fix
    (250, 400, 3, True),            # MAVLink 1: no extension fields
])
def test_gps_raw_int_without_an_accuracy_is_unknown(h_acc: int, v_acc: int, fix_type: int,
                                                    mavlink1: bool) -> None:
    sample = _gps_raw_int(h_acc, v_acc, fix_type, mavlink1=mavlink1)
    assert _in_force(sample) is None  # still a report: from its time on, unknown


class _DataFlash:
    """A DataFlash record as pymavlink's DFReader gives it: fields as attributes."""

    def __init__(self, kind: str, **fields: float) -> None:
        self._kind = kind
        self.__dict__.update(fields)

    def get_type(self) -> str:
        return self._kind


def test_dataflash_gpa_and_ulog_gps_accuracy() -> None:
    (s,) = samples_from_dataflash(_DataFlash("GPA", TimeUS=0, I=0, HAcc=0.52, VAcc=0.9), 3.0)
    assert s == GnssAccuracySample(3.0, 0.52, 0.9)
    assert _in_force(s) == PositionAccuracy(0.52, 0.9)
    (s,) = samples_from_dataflash(_DataFlash("GPA", TimeUS=0, I=0, HAcc=0.0, VAcc=0.0), 3.0)
    assert _in_force(s) is None
    assert samples_from_dataflash(_DataFlash("GPA", TimeUS=0, I=1, HAcc=0.5, VAcc=0.9),
                                  3.0) == ()  # the second receiver: not read

    pytest.importorskip("pyulog")
    from pdcov.telemetry.logs.ulog import _ulog_gnss_accuracy

    fields = {"eph": np.array([0.8, 0.8, -1.0]), "epv": np.array([1.5, 1.5, 1.5]),
              "fix_type": np.array([3, 1, 3])}
    got = [_in_force(s) for s in _ulog_gnss_accuracy(np.array([1.0, 2.0, 3.0]), fields)]
    assert got == [PositionAccuracy(0.8, 1.5), None, None]  # no fix; negative


def _series(*rows: tuple[float, float, float]) -> GnssAccuracySeries:
    return GnssAccuracySeries.from_samples([GnssAccuracySample(*r) for r in rows])


def test_the_report_in_force_is_the_latest_strictly_before_held_for_the_hold_time() -> None:
    assert GNSS_ACCURACY_HOLD_S == 5.0
    s = _series((1.0, 0.3, 0.5), (3.0, 0.0, 0.5), (4.0, 0.1, 0.2))
    t = np.array([0.5, 1.0, 1.5, 2.9, 3.5, 4.0, 4.1, 9.0, 9.2])
    h, v = accuracy_at(s, t)
    nan = math.nan
    np.testing.assert_array_equal(h, [nan, nan, 0.3, 0.3, nan, nan, 0.1, 0.1, nan])
    np.testing.assert_array_equal(v, [nan, nan, 0.5, 0.5, nan, nan, 0.2, 0.2, nan])
    assert position_accuracies(h[[2, 4]], v[[2, 4]]) == (PositionAccuracy(0.3, 0.5), None)
    h, _v = accuracy_at(_series(), t)
    assert np.isnan(h).all()


def test_the_live_history_keeps_every_report_that_can_be_in_force() -> None:
    old = _series((1.0, 0.3, 0.5), (2.0, 0.2, 0.4))
    new = _series((2.0, 0.1, 0.2), (8.0, 0.05, 0.1))
    merged = merge_accuracy(old, new, keep_from_s=7.0)  # 2.0 may hold until 7.0
    np.testing.assert_array_equal(merged.t_s, [2.0, 8.0])
    np.testing.assert_array_equal(merged.horizontal_m, [0.1, 0.05])  # equal times: new's
    t = np.array([7.0, 8.5])
    np.testing.assert_array_equal(accuracy_at(merged, t)[0],
                                  accuracy_at(_series((1.0, 0.3, 0.5), (2.0, 0.1, 0.2),
                                                      (8.0, 0.05, 0.1)), t)[0])


# --- the daemon's detections, and evaluate of its recording ------------------------------

def _run(tmp: Path, gnss_acc_mm: tuple[int, int] | None) -> tuple[list[dict], dict, Path]:
    """A hover (12 m, camera down) with GPS_RAW_INT of ``gnss_acc_mm`` and a person at the
    picture's centre in 10 frames: (the published detections, the status, the config)."""
    (tmp / "state").mkdir(parents=True)
    doc = dict(MISSION, mount=FIXED, vehicle_id="uav7")
    doc["service"] = {"state_dir": str(tmp / "state"), "frame_source": "zenoh",
                      "reorder_s": 0.0}
    cfg_path = tmp / "m.yaml"
    cfg_path.write_text(yaml.safe_dump(doc))
    d = Driver(cfg_path, tmp / "rec")
    msgs = Hover(seconds=4.0, gnss_acc_mm=gnss_acc_mm).messages()
    d.link(b"".join(pack(m, seq=i) for i, m in enumerate(msgs)))
    person = Box("person", 0.9, 310.0, 200.0, 18.0, 40.0)
    d.frames(encode_frames_v2([FrameBoxes(2.0 + 0.2 * k, (person,)) for k in range(10)]))
    d.core.process()
    for _ in range(3):
        d.tick(DETECTIONS_PERIOD_S)
    d.recorder.close()
    status = decode_status(encode_status(d.core.status(d.now_s, LinkReport())[0]))
    return [x for msg in d.published for x in msg["detections"]], status, cfg_path


def test_a_smaller_reported_accuracy_gives_smaller_sigmas_live_and_offline(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """12 m over the ground, camera down: with the configured 1 m position sigma a box's
    sigma_m is at least 1 m; with a reported 2 cm it is the attitude's 12 m x 0.5 deg
    (0.10 m) and the pixel's, so below 0.3 m. evaluate of the recording gives the same."""
    sharp, status, cfg_path = _run(tmp_path / "sharp", (20, 40))
    blunt, blunt_status, _ = _run(tmp_path / "blunt", None)
    assert len(sharp) == len(blunt) == 10
    assert all(0.1 < x["sigma_m"] < 0.3 for x in sharp), [x["sigma_m"] for x in sharp]
    assert all(x["sigma_m"] >= 1.0 for x in blunt), [x["sigma_m"] for x in blunt]
    assert status["pose"]["gnss_h_acc_m"] == 0.02
    assert blunt_status["pose"]["gnss_h_acc_m"] is None

    rec = next((tmp_path / "sharp" / "rec").glob("flight-*.tlog"))
    assert read_flight_log(rec).gnss_accuracy.horizontal_m[0] == 0.02
    out = tmp_path / "offline"
    assert pdcov_main(["evaluate", "--config", str(cfg_path), "--log", str(rec), "--out",
                       str(out), "--no-progress"]) == 0
    offline = decode_detections((out / "detections.json").read_bytes(), vehicle_id="uav7")
    assert without_epoch(offline["detections"]) == without_epoch(sharp)
    assert ("GNSS accuracy: 8 reports, each in force for 5 s; 10 of 10 frames used had one "
            "(horizontal 0.02-0.02 m" in capsys.readouterr().out)


# --- real logs ---------------------------------------------------------------------------

@pytest.mark.skipif(not REAL.is_dir(), reason=f"{REAL} not present")
def test_real_ardupilot_logs_report_the_simulated_receiver_s_accuracy() -> None:
    """ArduPilot's SITL GPS reports 0.3 m (its SIM_GPS accuracy) in GPS_RAW_INT and GPA;
    before a 3D fix none."""
    for name in ("ardupilot_sitl_servo_gimbal.tlog", "ardupilot_sitl_servo_gimbal.BIN"):
        g = read_flight_log(REAL / name).gnss_accuracy
        known = np.isfinite(g.horizontal_m)
        assert len(g.t_s) > 700 and known.mean() > 0.9, name
        np.testing.assert_array_equal(np.unique(g.horizontal_m[known]), [0.3])


# --- the simulator's receiver ------------------------------------------------------------

@pytest.mark.parametrize("sigma_m", [0.3, 0.05])
def test_the_simulator_reports_the_accuracy_its_receiver_has(sigma_m: float) -> None:
    """GPS_RAW_INT of a vehicle at rest: h_acc = the receiver's horizontal 1-sigma per axis
    (mm), v_acc 5/3 of it, and the reported positions scatter about the truth by that much
    (4000 messages of a random walk with phi 0.95: as many as 4000 (1 - phi) / (1 + phi) =
    100 independent ones, so the measured sd is within about 7 %, checked to 25 %)."""
    from pdcov_sitl.dynamics import VehicleState
    from pdcov_sitl.messages import MessageBuilder, Snapshot

    home = (47.397742, 8.545594, 488.0)
    builder = MessageBuilder(mavlink.MAVLink(None), "ardupilot", home, 3,
                             gnss_accuracy_m=sigma_m)
    state = VehicleState(0.0, *home, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, 0.0, 0.0,
                         0.0, 0.0, 0.0, 0.0)
    enu, accuracies = [], set()
    for k in range(4000):
        snap = Snapshot(state, 200 * k, 0, (0.0, 0.0, 0.0), "waypoint", True, None, 0, 0,
                        0.0, 1.0)
        msg = builder.build("GPS_RAW_INT", snap)
        accuracies.add((msg.h_acc, msg.v_acc))
        enu.append(geodetic_to_enu(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3,
                                   Origin(*home)).reshape(3))
    assert accuracies == {(round(sigma_m * 1000), round(sigma_m * 5000 / 3))}
    sd = np.std(np.array(enu), axis=0)
    np.testing.assert_allclose(sd, [sigma_m, sigma_m, sigma_m * 5 / 3], rtol=0.25)
    with pytest.raises(ValueError, match="gnss_accuracy_m 0.0: expected 0.001..100 m"):
        MessageBuilder(mavlink.MAVLink(None), "ardupilot", home, 3, gnss_accuracy_m=0.0)


@pytest.mark.parametrize("value", ["0", "nan", "150"])
def test_fly_refuses_a_gnss_accuracy_it_cannot_send(value: str, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    from pdcov_sitl.cli import main as sitl_main

    assert sitl_main(["fly", "--config", str(tmp_path / "m.yaml"), "--plan",
                      str(tmp_path / "p.plan"), "--out", str(tmp_path),
                      "--gnss-accuracy-m", value]) == 2
    assert (f"pdcov-sitl fly: --gnss-accuracy-m {float(value)}: expected 0.001 <= H <= 100 m"
            in capsys.readouterr().err)
