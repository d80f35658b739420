"""The position-estimate rule (telemetry/estimator.py): the autopilot's estimator status read
from MAVLink (EKF_STATUS_REPORT, ESTIMATOR_STATUS), DataFlash (XKF4/NKF4) and ULog, the
verdicts by hand, a hover with a GPS glitch window live (bytes through the daemon's read
path) equal to offline (the same bytes as a tlog), the link's requests, the simulator's
reports, the config key, the real ArduPilot logs (only frames on the ground lost), and a
PX4-like simulator flight with a glitch through real UDP and Zenoh (live = offline)."""

from __future__ import annotations

import math
import os
import struct
from pathlib import Path

import numpy as np
import pytest
import yaml

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.config.load import mission_from_dict
from pdcov.core.pose import FixedMount
from pdcov.errors import ConfigError
from pdcov.flight.frame_decision import Framing
from pdcov.flight.log_frames import poses_from_log
from pdcov.service.coverage import Due
from pdcov.service.settings import load_serve_config
from pdcov.telemetry.adapters import NAV_GPS_GLITCHING, sample_from_mavlink
from pdcov.telemetry.estimator import (
    CONSTANT_POSITION,
    ESTIMATOR_HOLD_S,
    GPS_GLITCHING,
    NO_ABSOLUTE_POSITION,
    estimator_reasons,
    merge_estimator,
)
from pdcov.telemetry.link_protocol import EKF_STATUS_REPORT, ESTIMATOR_STATUS, LinkProtocol
from pdcov.telemetry.logs import read_flight_log
from pdcov.telemetry.samples import EstimatorSample
from pdcov.telemetry.series import EstimatorSeries
from tests.support.harness import small_mission
from tests.support.link_feed import (
    GROUND_M,
    LAT_DEG,
    LON_DEG,
    LinkFeed,
    offline_of,
    pack,
    serve_config,
)
from tests.support.ulog_fixture import write_ulog

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "real-logs"
HOME = dict(origin_lat_deg=-35.363261, origin_lon_deg=149.165230, ground_alt_msl_m=None)
OK_FLAGS = 831  # the real ArduCopter log's flags in flight (both enums' good bits)


def decoded(msg: mavlink.MAVLink_message) -> mavlink.MAVLink_message:
    """``msg`` packed and parsed back, as a link delivers it."""
    return mavlink.MAVLink(None).parse_char(bytearray(pack(msg)))


def series(*rows: tuple[float, bool, bool, bool]) -> EstimatorSeries:
    return EstimatorSeries.from_samples([EstimatorSample(*r) for r in rows])


# --- adapters ----------------------------------------------------------------------------

def test_ekf_status_report_bits() -> None:
    mav = mavlink.MAVLink(None)
    good = sample_from_mavlink(decoded(mav.ekf_status_report_encode(OK_FLAGS, 0.1, 0.1, 0.1,
                                                                    0.1, 0, 0)), 5.0)
    assert good == EstimatorSample(5.0, True, False, False)
    glitch = sample_from_mavlink(decoded(mav.ekf_status_report_encode(
        OK_FLAGS | mavlink.EKF_GPS_GLITCHING, 0.1, math.nan, 0.1, 0.1, 0, 0)), 6.0)
    assert glitch == EstimatorSample(6.0, True, False, True)  # NaN variance: not read
    # Before GPS (the real log's 167: attitude, velocities, vertical, constant position).
    const = sample_from_mavlink(decoded(mav.ekf_status_report_encode(167, 0, 0, 0, 0, 0, 0)), 1)
    assert const == EstimatorSample(1, False, True, False)
    # 1024 is EKF_UNINITIALIZED here (ESTIMATOR_GPS_GLITCH in the other enum).
    uninit = sample_from_mavlink(decoded(mav.ekf_status_report_encode(1024, 0, 0, 0, 0, 0, 0)), 1)
    assert uninit == EstimatorSample(1, False, False, False)
    # Bits no enum defines change nothing.
    odd = sample_from_mavlink(decoded(mav.ekf_status_report_encode(OK_FLAGS | 0x4000 | 0x800,
                                                                   0, 0, 0, 0, 0, 0)), 1)
    assert odd == EstimatorSample(1, True, False, False)
    # All zero: ArduPilot's AHRS runs no EKF (DCM): no verdict at all.
    assert sample_from_mavlink(decoded(mav.ekf_status_report_encode(0, 0, 0, 0, 0, 0, 0)),
                               1) is None


def test_estimator_status_bits() -> None:
    mav = mavlink.MAVLink(None)

    def sample(flags: int) -> object:
        return sample_from_mavlink(decoded(mav.estimator_status_encode(
            123, flags, 0.1, math.nan, 0.1, 0.1, 0, 0, 0.5, 0.5)), 2.0)

    assert sample(OK_FLAGS) == EstimatorSample(2.0, True, False, False)
    assert sample(OK_FLAGS | mavlink.ESTIMATOR_GPS_GLITCH) == EstimatorSample(2.0, True, False,
                                                                              True)
    # PX4 sets its constant-position bit at rest with a good position: no skip from it.
    assert sample(OK_FLAGS | 128) == EstimatorSample(2.0, True, True, False)
    assert sample(0) == EstimatorSample(2.0, False, False, False)


# --- the rule by hand --------------------------------------------------------------------

def test_rule_by_hand() -> None:
    est = series((1.0, True, False, False), (2.0, True, False, True),
                 (3.0, False, True, False), (4.0, False, False, False),
                 (5.0, True, False, False))
    t = np.array([0.5, 1.0, 1.5, 2.0, 2.5, 3.5, 4.5, 5.5, 5.0 + ESTIMATOR_HOLD_S,
                  5.01 + ESTIMATOR_HOLD_S])
    reason, judged = estimator_reasons(est, t)
    assert list(reason) == ["", "", "", "", GPS_GLITCHING, CONSTANT_POSITION,
                            NO_ABSOLUTE_POSITION, "", "", ""]
    # Strictly before: the report at 1.0 does not judge the frame at 1.0; held 3 s.
    assert list(judged) == [False, False, True, True, True, True, True, True, True, False]
    none_reason, none_judged = estimator_reasons(series(), t)
    assert not none_judged.any() and not any(none_reason)


def test_merge_keeps_order_newest_and_what_can_still_apply() -> None:
    old = series((1.0, True, False, False), (2.0, True, False, False))
    new = series((2.0, True, False, True), (0.5, False, False, False))
    m = merge_estimator(old, new)
    assert list(m.t_s) == [0.5, 1.0, 2.0] and list(m.gps_glitch) == [False, False, True]
    cut = merge_estimator(old, new, keep_from_s=4.5)  # 4.5 - 3 s: 1.0 can no longer apply
    assert list(cut.t_s) == [2.0]


# --- a hover with a glitch window: live (the daemon's read path) = offline (tlog) --------

GLITCH_S = (10.0, 14.0)


def glitch_hover(seconds: float = 30.0, status: bool = True) -> list[mavlink.MAVLink_message]:
    """A vehicle hovering 12 m over the domain (fixed camera down), ATTITUDE 25 Hz,
    GLOBAL_POSITION_INT 10 Hz, EKF_STATUS_REPORT 2.5 Hz (no boot time: it is stamped with
    the ATTITUDE before it) saying GPS glitching from 10 to 14 s of autopilot time."""
    mav = mavlink.MAVLink(None)
    lat_e7 = round((LAT_DEG + 15 / 111_320.0) * 1e7)
    lon_e7 = round((LON_DEG + 15 / (111_320.0 * math.cos(math.radians(LAT_DEG)))) * 1e7)
    out = [mav.heartbeat_encode(2, 3, 128 | 1, 4, 4),
           mav.home_position_encode(round(LAT_DEG * 1e7), round(LON_DEG * 1e7),
                                    round(GROUND_M * 1000), 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)]
    for k in range(int(seconds * 25)):
        ms = 1000 + 40 * k
        if k % 25 == 0:
            out.append(mav.heartbeat_encode(2, 3, 128 | 1, 4, 4))
        out.append(mav.attitude_encode(ms, 0.01, -0.02, 0.3, 0, 0, 0))
        if k % 5 == 2:  # 60, 260, ... ms: positions between the frames
            out.append(mav.global_position_int_encode(ms, lat_e7, lon_e7,
                                                      round((GROUND_M + 12) * 1000), 12_000,
                                                      0, 0, 0, 0))
        if status and k % 10 == 0:  # 2.5 Hz, right after the ATTITUDE of 1.0, 1.4, ... s
            glitch = GLITCH_S[0] <= ms / 1000 < GLITCH_S[1]
            out.append(mav.ekf_status_report_encode(
                OK_FLAGS | (mavlink.EKF_GPS_GLITCHING if glitch else 0), 0.1,
                1.5 if glitch else 0.1, 0.1, 0.1, 0, 0))
    return out


def write_tlog(path: Path, msgs: list[mavlink.MAVLink_message]) -> None:
    with path.open("wb") as f:
        for i, m in enumerate(msgs):
            f.write(struct.pack(">Q", 1_700_000_000_000_000 + 1000 * i) + pack(m, seq=i))


def live_and_offline(tmp: Path, msgs: list[mavlink.MAVLink_message], **log: object
                     ) -> tuple[LinkFeed, object, dict]:
    cfg = serve_config(tmp, gimbal=False)
    if log:
        doc = yaml.safe_load(Path(cfg.mission.source).read_text())
        doc["log"] = {**doc.get("log", {}), **log}
        Path(cfg.mission.source).write_text(yaml.safe_dump(doc))
        cfg = load_serve_config(cfg.mission.source)
    feed = LinkFeed(cfg)
    live, poll = feed.live, feed.live.poll
    notes: list[str] = []

    def noting_poll(now_s: float) -> Due:  # what the daemon logs (Due.notes)
        due = poll(now_s)
        notes.extend(due.notes)
        return due

    live.poll = noting_poll  # type: ignore[method-assign]
    for i, m in enumerate(msgs):
        feed.feed(pack(m, seq=i), i * 0.001)
    feed.tick(len(msgs) * 0.001 + 1.0)
    feed.notes = notes  # type: ignore[attr-defined]
    tlog = tmp / "hover.tlog"
    write_tlog(tlog, msgs)
    lp, grid = offline_of(cfg, tlog)
    return feed, lp, {"grid": grid}


def test_glitch_window_live_equals_offline(tmp_path: Path) -> None:
    feed, lp, off = live_and_offline(tmp_path, glitch_hover())
    live = feed.live
    rate = feed.cfg.mission.first_camera.frame_rate_hz
    # Reports at 1.0, 1.4, ... s: glitching from 10.2 to 13.8 s; frames every 0.2 s from
    # 1.08 s. Skipped: the frames after the 10.2 s report (strictly after it) up to the
    # 14.2 s one, 10.28 ... 14.08 s (the 13.8 s report is in force at 14.08 s).
    assert live.t0_s == pytest.approx(1.08)
    lattice = live.t0_s + np.arange(0, 40 * rate) / rate
    expected = int(((lattice > 10.2) & (lattice <= 14.2)).sum())
    assert expected == 20
    skipped = dict(live.counters.skipped)
    assert skipped.get(GPS_GLITCHING) == expected, skipped
    assert any(f"{GPS_GLITCHING} {expected}" in line for line in lp.summary_lines), \
        lp.summary_lines
    # Live equals offline, frame for frame and cell for cell.
    assert live.counters.used == live.grid.frames == off["grid"].frames > 50
    np.testing.assert_array_equal(live.grid.log_miss_d, off["grid"].log_miss_d)
    np.testing.assert_array_equal(live.grid.n_obs, off["grid"].n_obs)
    assert not [p for p in lp.poses if 10.2 < p.t_s <= 14.2]
    assert [p for p in lp.poses if 10.0 < p.t_s <= 10.2]  # before the EKF said so
    status = feed.status()
    assert status["frames"]["skipped"][GPS_GLITCHING] == expected
    assert feed.notes == []
    # The first report (1.0 s) precedes the first frame: every frame was judged.
    assert "frames_without_estimator_status" not in status["faults"], status["faults"]
    assert EKF_STATUS_REPORT in sum(status["link"]["intervals"].values(), [])


def test_no_status_on_the_link_skips_nothing_and_says_so(tmp_path: Path) -> None:
    feed, lp, off = live_and_offline(tmp_path, glitch_hover(status=False))
    live = feed.live
    assert not any(r.startswith("position estimate") for r in live.counters.skipped)
    assert live.counters.used == off["grid"].frames > 100
    np.testing.assert_array_equal(live.grid.log_miss_d, off["grid"].log_miss_d)
    assert live.counters.faults["frames_without_estimator_status"] == live.counters.used
    assert len(feed.notes) == 1 and "no estimator status" in feed.notes[0], feed.notes
    assert any("carries no estimator status" in line for line in lp.summary_lines)


def test_rule_switched_off(tmp_path: Path) -> None:
    feed, lp, off = live_and_offline(tmp_path, glitch_hover(), estimator_status=False)
    assert not any(r.startswith("position estimate") for r in feed.live.counters.skipped)
    assert feed.live.counters.used == off["grid"].frames
    np.testing.assert_array_equal(feed.live.grid.log_miss_d, off["grid"].log_miss_d)
    assert any("not checked (log.estimator_status is false)" in line
               for line in lp.summary_lines)
    # Nor asked for on the link.
    assert all(EKF_STATUS_REPORT not in ids for ids in
               feed.status()["link"]["intervals"].values())


# --- the link asks for the autopilot's own status message --------------------------------

@pytest.mark.parametrize(("autopilot", "wanted"), [(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                    EKF_STATUS_REPORT),
                                                   (mavlink.MAV_AUTOPILOT_PX4,
                                                    ESTIMATOR_STATUS)])
def test_link_requests_the_estimator_stream(autopilot: int, wanted: int) -> None:
    proto = LinkProtocol(mavlink.MAVLink(None), system_id=None, intervals={30: 25.0},
                         param_names=(), param_timeout_s=5.0, estimator_hz=5.0)
    hb = decoded(mavlink.MAVLink(None).heartbeat_encode(2, autopilot, 128, 0, 4))
    proto.receive(hb, 0.0)
    sent = [m for m in proto.poll(0.0) if m.get_type() == "COMMAND_LONG"]
    asked = {int(m.param1): m.param2 for m in sent
             if m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL}
    assert asked == {30: 40_000, wanted: 200_000}
    # Only the autopilot's own estimator counts (the log readers read no other).
    report = mavlink.MAVLink(None).ekf_status_report_encode(OK_FLAGS, 0, 0, 0, 0, 0, 0)
    own = mavlink.MAVLink(None).parse_char(bytearray(pack(report, component_id=1)))
    other = mavlink.MAVLink(None).parse_char(bytearray(pack(report, component_id=191)))
    assert [type(s) for s in proto.receive(own, 0.1)] == [EstimatorSample]
    assert proto.receive(other, 0.2) == []
    off = LinkProtocol(mavlink.MAVLink(None), system_id=None, intervals={30: 25.0},
                       param_names=(), param_timeout_s=5.0, estimator_hz=None)
    off.receive(hb, 0.0)
    assert {int(m.param1) for m in off.poll(0.0) if m.get_type() == "COMMAND_LONG"
            and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL} == {30}


# --- the simulator reports its glitch as an EKF would ------------------------------------

@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_simulator_reports_glitch_for_its_window(autopilot: str) -> None:
    from pdcov_sitl.dynamics import VehicleState
    from pdcov_sitl.faults import FaultSpec
    from pdcov_sitl.messages import STREAMS_HZ, MessageBuilder, Snapshot

    name = "EKF_STATUS_REPORT" if autopilot == "ardupilot" else "ESTIMATOR_STATUS"
    assert 0.5 <= STREAMS_HZ[autopilot][name] <= 4.0
    spec = FaultSpec.parse("gps_glitch=30+4:20")
    mav = mavlink.MAVLink(None)
    builder = MessageBuilder(mav, autopilot, (LAT_DEG, LON_DEG, GROUND_M), 0)
    state = VehicleState.__new__(VehicleState)  # the status builders read no state
    got = {}
    for t in (29.9, 30.0, 33.9, 34.0):
        snap = Snapshot(state, round(t * 1000), 0, spec.gps_offset_ned_m(t), "waypoint", True,
                        None, 0, 0, 0.0, 1.0, spec.gps_glitching(t))
        msg = decoded(builder.build(name, snap))
        assert msg.get_type() == name
        got[t] = sample_from_mavlink(msg, t)
    assert [s.gps_glitch for s in got.values()] == [False, True, True, False]
    assert all(s.pos_horiz_abs for s in got.values())


# --- config ------------------------------------------------------------------------------

def test_config_key_checked() -> None:
    doc = small_mission(vehicle_id="cfg")
    assert mission_from_dict(doc).estimator_status is True
    assert mission_from_dict({**doc, "log": {"estimator_status": False}}).estimator_status \
        is False
    with pytest.raises(ConfigError, match=r"log\.estimator_status: expected true or false"):
        mission_from_dict({**doc, "log": {"estimator_status": "no"}})
    with pytest.raises(ConfigError, match="did you mean 'estimator_status'"):
        mission_from_dict({**doc, "log": {"estimator_statu": True}})


# --- real ArduPilot logs -----------------------------------------------------------------

real = pytest.mark.skipif(not REAL.is_dir(), reason=f"{REAL} not present")


@real
def test_real_logs_carry_the_status_they_should() -> None:
    tlog = read_flight_log(REAL / "ardupilot_sitl_servo_gimbal.tlog")
    assert tlog.estimator_source.startswith("EKF_STATUS_REPORT")
    assert len(tlog.estimator.t_s) == 597 and not tlog.estimator.gps_glitch.any()
    dflash = read_flight_log(REAL / "ardupilot_sitl_servo_gimbal.BIN")
    assert dflash.estimator_source == "XKF4 SS (EKF3, primary core)"
    assert 1500 < len(dflash.estimator.t_s) < 1700  # 10 Hz of the primary core only
    old = read_flight_log(REAL / "beast_log_0036_mechanical_failure.bin")
    assert old.estimator_source.startswith("NKF4") and old.estimator.pos_horiz_abs.all()
    # AHRS_EKF_TYPE 10 (SITL's own AHRS): all-zero EKF_STATUS_REPORTs, no verdict.
    vtol = read_flight_log(REAL / "uavlogviewer_vtol.tlog")
    assert len(vtol.estimator.t_s) == 0 and vtol.estimator_source == ""


@real
def test_dataflash_3_4_follows_a_lane_switch(tmp_path: Path) -> None:
    """ArduCopter 3.4 logs EKF2 core 0 as NKF4 and core 1 as NKF9, each with PI, the
    primary core. The real 3.4.4 flight never switched (PI 0 throughout: core 1's reports
    unused); the same log with a switch to core 1 written into its last 502 records (PI 1
    in NKF4 and NKF9) and core 1 glitching all along: core 1's flags apply from the switch
    on, never before."""
    from pymavlink import DFReader

    src = REAL / "beast_log_0036_mechanical_failure.bin"
    assert read_flight_log(src).estimator_source == "NKF4 SS (EKF2, primary core)"
    reader = DFReader.DFReader_binary(str(src), zero_time_base=True)
    data = bytearray(src.read_bytes())
    for name in ("NKF4", "NKF9"):
        fmt = reader.formats[reader.name_to_id[name]]
        cols = fmt.columns
        assert cols[11:] == ["SS", "GPS", "PI"] and fmt.len == 35
        ss_at = 3 + struct.calcsize(fmt.msg_struct[:12])  # after the 3-byte header
        for k, offset in enumerate(reader.offsets[reader.name_to_id[name]]):
            if name == "NKF9":
                (ss,) = struct.unpack_from("<H", data, offset + ss_at)
                struct.pack_into("<H", data, offset + ss_at, ss | NAV_GPS_GLITCHING)
            if k >= 1000:
                data[offset + fmt.len - 1] = 1  # PI, int8, last
    switched = tmp_path / "switched.bin"
    switched.write_bytes(bytes(data))
    log = read_flight_log(switched)
    assert log.estimator_source == "NKF4/NKF9 SS (EKF2, primary core; 502 reports of core 1)"
    assert list(log.estimator.gps_glitch) == [False] * 1000 + [True] * 502


LOST_ON_THE_GROUND = {"ardupilot_sitl_servo_gimbal.tlog": 159,
                      "ardupilot_sitl_servo_gimbal.BIN": 158,
                      "uavlogviewer_flight_logs.tlog": 161,
                      "beast_log_0036_mechanical_failure.bin": 0,
                      "uavlogviewer_vtol.tlog": 0}
"""Frames (5 Hz) the rule skips in each healthy real flight: all before the EKF fused GPS
(constant position mode, 10-42 s of boot time), on the ground."""


@real
@pytest.mark.parametrize("name", sorted(LOST_ON_THE_GROUND))
def test_real_healthy_flights_lose_only_frames_on_the_ground(name: str) -> None:
    on = poses_from_log(REAL / name, Framing(FixedMount(), 5.0), **HOME)
    off = poses_from_log(REAL / name, Framing(FixedMount(), 5.0, estimator_status=False),
                         **HOME)
    kept = {p.t_s for p in on.poses}
    assert kept <= {p.t_s for p in off.poses}
    lost = np.array(sorted({p.t_s for p in off.poses} - kept))
    assert len(lost) == LOST_ON_THE_GROUND[name]
    if len(lost):
        pos = read_flight_log(REAL / name).position
        height_m = np.interp(lost, pos.t_s, pos.relative_alt_m)
        assert height_m.max() < 0.5 and lost.max() < 42.0, (height_m.max(), lost.max())
        assert any(f"{CONSTANT_POSITION} {len(lost)}" in line for line in on.summary_lines)
    assert len(kept) > 500


# --- end to end: the simulator (PX4-like) over real UDP -> pdcov serve -> Zenoh ----------


# --- PX4 ULog ----------------------------------------------------------------------------

def test_ulog_estimator_status(tmp_path: Path) -> None:
    """estimator_status.solution_status_flags (ESTIMATOR_STATUS_FLAGS, what PX4 sends as the
    MAVLink message's flags): glitching 1-2 s, then no absolute position."""
    att = ([("uint64_t", "timestamp"), ("float[4]", "q")],
           [(int(k * 1e5), 1.0, 0.0, 0.0, 0.0) for k in range(40)])
    pos = ([("uint64_t", "timestamp"), ("double", "lat"), ("double", "lon"), ("float", "alt")],
           [(int(k * 1e5), LAT_DEG, LON_DEG, GROUND_M + 10) for k in range(40)])
    flags = [OK_FLAGS] * 10 + [OK_FLAGS | mavlink.ESTIMATOR_GPS_GLITCH] * 10 + [167] * 10
    est = ([("uint64_t", "timestamp"), ("uint16_t", "solution_status_flags")],
           [(int(k * 1e5), f) for k, f in enumerate(flags)])
    log = read_flight_log(write_ulog(tmp_path / "e.ulg", {
        "vehicle_attitude": att, "vehicle_global_position": pos, "estimator_status": est}))
    assert log.estimator_source == "estimator_status solution_status_flags, EKF instance 0"
    e = log.estimator
    assert len(e.t_s) == 30
    assert list(e.gps_glitch) == [False] * 10 + [True] * 10 + [False] * 10
    assert list(e.pos_horiz_abs) == [True] * 20 + [False] * 10
    reason, _ = estimator_reasons(e, np.array([0.55, 1.55, 2.55]))
    assert list(reason) == ["", GPS_GLITCHING, CONSTANT_POSITION]


def _ulog_ekfs(tmp: Path, selections: list[tuple[int, int]] | None) -> Path:
    """A 4 s PX4 log (reports every 0.1 s) with three EKF2 instances, as with
    EKF2_MULTI_IMU 3: instance 0 glitching from 1.0 s; instance 1 good, then without
    absolute position from 3.0 s; instance 2 glitching all along. ``selections``:
    estimator_selector_status rows (t_us, primary_instance), None for no such topic."""
    att = ([("uint64_t", "timestamp"), ("float[4]", "q")],
           [(int(k * 1e5), 1.0, 0.0, 0.0, 0.0) for k in range(40)])
    pos = ([("uint64_t", "timestamp"), ("double", "lat"), ("double", "lon"), ("float", "alt")],
           [(int(k * 1e5), LAT_DEG, LON_DEG, GROUND_M + 10) for k in range(40)])
    glitch = OK_FLAGS | mavlink.ESTIMATOR_GPS_GLITCH
    flags = {0: [OK_FLAGS] * 10 + [glitch] * 30, 1: [OK_FLAGS] * 30 + [167] * 10,
             2: [glitch] * 40}
    fields = [("uint64_t", "timestamp"), ("uint16_t", "solution_status_flags")]
    topics: dict = {"vehicle_attitude": att, "vehicle_global_position": pos}
    for inst, f in flags.items():
        topics["estimator_status" if inst == 0 else ("estimator_status", inst)] = (
            fields, [(int(k * 1e5), v) for k, v in enumerate(f)])
    if selections is not None:  # msg/EstimatorSelectorStatus.msg (the fields read)
        topics["estimator_selector_status"] = (
            [("uint64_t", "timestamp"), ("uint8_t", "primary_instance"),
             ("uint8_t", "instances_available")], [(t, i, 3) for t, i in selections])
    return write_ulog(tmp / "ekfs.ulg", topics)


def test_ulog_follows_the_primary_ekf_instance(tmp_path: Path) -> None:
    """PX4 with several EKF2 instances: the reports of the instance estimator_selector_status
    names primary at their time (0, a switch to 1 at 1.45 s, back to 0 at 3.55 s); instance
    2 is never used; the summary line names the instances and when."""
    path = _ulog_ekfs(tmp_path, [(50_000, 0), (1_450_000, 1), (2_050_000, 1),
                                 (3_550_000, 0)])
    log = read_flight_log(path)
    e = log.estimator
    np.testing.assert_allclose(e.t_s, np.arange(40) * 0.1, atol=1e-9)  # one per report time
    t = np.array([0.55, 1.25, 1.75, 3.25, 3.75])
    reason, judged = estimator_reasons(e, t)
    assert judged.all()
    # Instance 0 only (the reader before) would say glitching at 1.75 and 3.25 s.
    assert list(reason) == ["", GPS_GLITCHING, "", CONSTANT_POSITION, GPS_GLITCHING]
    assert log.estimator_source == (
        "estimator_status solution_status_flags, the primary EKF instance "
        "(estimator_selector_status.primary_instance): 0 from 0.00 s, 1 from 1.45 s, 0 from "
        "3.55 s; instances logged [0, 1, 2]")
    lp = poses_from_log(path, Framing(FixedMount(), 10.0), origin_lat_deg=LAT_DEG,
                        origin_lon_deg=LON_DEG, ground_alt_msl_m=GROUND_M)
    line = next(x for x in lp.summary_lines if x.startswith("position estimate:"))
    assert "1 from 1.45 s" in line and "40 reports" in line, line
    # Frames 1.1..1.5 s (instance 0 glitching) and 3.1..3.6 (instance 1 without absolute
    # position; 3.6 by instance 1's report at 3.5 s, strictly before) and 3.7.. (0 again).
    skipped = np.round(lp.skipped_t_s, 3).tolist()
    assert skipped == [1.1, 1.2, 1.3, 1.4, 1.5, 3.1, 3.2, 3.3, 3.4, 3.5, 3.6, 3.7, 3.8,
                       3.9], skipped


def test_ulog_several_ekfs_without_a_selector_use_instance_0(tmp_path: Path) -> None:
    log = read_flight_log(_ulog_ekfs(tmp_path, None))
    assert list(log.estimator.gps_glitch) == [False] * 10 + [True] * 30
    assert log.estimator_source.endswith(
        "EKF instance 0 of instances [0, 1, 2] logged (no estimator_selector_status: the "
        "primary is not known)"), log.estimator_source
