"""The simulator's autopilot protocol in memory: stream schedule stepped in simulated time,
commands, parameters and the mission protocol, with pdcov's own uploader as the client
(bytes passed whole, byte by byte, and among junk)."""

from __future__ import annotations

import random
from itertools import pairwise

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from pdcov.core.geodesy import Origin
from pdcov.planning.plan import Plan, Waypoint
from pdcov.planning.plan_items import home_item, mission_items
from pdcov.telemetry.upload import MissionUpload
from pdcov_sitl.protocol import AutopilotProtocol, StreamSchedule, message_id

GCS = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
ORIGIN = Origin(39.35, -76.33, 12.5)
PLAN = Plan((Waypoint(0.0, 0.0, 10.0, 5.0), Waypoint(0.0, 40.0, 10.0, 5.0, 2.0),
             Waypoint(8.0, 40.0, 10.0, 5.0), Waypoint(8.0, 0.0, 10.0, 5.0)))


def count_sends(schedule: StreamSchedule, t_from_s: float, t_to_s: float,
                step_s: float = 1 / 120) -> dict[str, list[float]]:
    sent: dict[str, list[float]] = {}
    t = t_from_s
    while t < t_to_s:
        for name in schedule.due(t):
            sent.setdefault(name, []).append(t)
        t += step_s
    return sent


def test_streams_keep_their_rates_with_jitter():
    schedule = StreamSchedule({"ATTITUDE": 50.0, "GLOBAL_POSITION_INT": 10.0,
                               "SYS_STATUS": 1.0, "GPS_RAW_INT": 0.0}, random.Random(3))
    sent = count_sends(schedule, 0.0, 60.0, step_s=0.001)
    assert len(sent["ATTITUDE"]) == pytest.approx(3000, abs=2)
    assert len(sent["GLOBAL_POSITION_INT"]) == pytest.approx(600, abs=2)
    assert len(sent["SYS_STATUS"]) == pytest.approx(60, abs=1)
    assert "GPS_RAW_INT" not in sent
    gaps = [b - a for a, b in pairwise(sent["GLOBAL_POSITION_INT"])]
    assert min(gaps) > 0.07 and max(gaps) < 0.13  # jittered, never bunched
    assert max(gaps) - min(gaps) > 0.004  # and not a perfect clock


def test_streams_are_deterministic_for_a_seed():
    def run(seed):
        return count_sends(StreamSchedule({"ATTITUDE": 25.0}, random.Random(seed)), 0, 5)
    assert run(1) == run(1)
    assert run(1) != run(2)


def test_set_rate_request_once_and_reset():
    schedule = StreamSchedule({"ATTITUDE": 10.0, "HOME_POSITION": 0.0}, random.Random(0))
    count_sends(schedule, 0.0, 1.0)
    schedule.set_rate("ATTITUDE", 40.0, 1.0)
    assert len(count_sends(schedule, 1.0, 11.0)["ATTITUDE"]) == pytest.approx(400, abs=2)
    schedule.request_once("HOME_POSITION")
    assert schedule.due(11.0)[0] == "HOME_POSITION"
    assert "HOME_POSITION" not in count_sends(schedule, 11.01, 12.0)
    schedule.reset()
    assert len(count_sends(schedule, 12.0, 22.0)["ATTITUDE"]) == pytest.approx(100, abs=2)


def test_stream_schedule_rejects_unknown_messages_and_bad_rates():
    with pytest.raises(ValueError, match="ATTITUDEX"):
        StreamSchedule({"ATTITUDEX": 1.0}, random.Random(0))
    with pytest.raises(ValueError, match="-1"):
        StreamSchedule({"ATTITUDE": -1.0}, random.Random(0))


def make_protocol(autopilot="ardupilot", params=None):
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    schedule = StreamSchedule({"ATTITUDE": 10.0, "HOME_POSITION": 0.0}, random.Random(0))
    params = {"MNT1_TYPE": 1.0, "MNT1_PITCH_MIN": -90.0, "MNT1_PITCH_MAX": 20.0} \
        if params is None else params
    return AutopilotProtocol(mav, system_id=1, autopilot=autopilot, params=params,
                             schedule=schedule)


def command(cmd, *params, target=(1, 1)):
    p = list(params) + [0.0] * (7 - len(params))
    return GCS.command_long_encode(*target, cmd, 0, *p)


def decoded(msg):
    """The message as a receiver would see it: packed by the vehicle and parsed again."""
    packet = msg.pack(mavlink2.MAVLink(None, srcSystem=1, srcComponent=1))
    return mavlink2.MAVLink(None).decode(bytearray(packet))


def from_gcs(msg):
    return decoded_from(GCS, msg)


def decoded_from(mav, msg):
    return mavlink2.MAVLink(None).decode(bytearray(msg.pack(mav)))


@pytest.mark.parametrize(("msg_id", "interval_us", "result"), [
    (message_id("ATTITUDE"), 20_000, mavlink2.MAV_RESULT_ACCEPTED),
    (message_id("ATTITUDE"), -1, mavlink2.MAV_RESULT_ACCEPTED),
    (message_id("ATTITUDE"), 0, mavlink2.MAV_RESULT_ACCEPTED),
    (message_id("VFR_HUD"), 20_000, mavlink2.MAV_RESULT_UNSUPPORTED),
    (60_000, 20_000, mavlink2.MAV_RESULT_DENIED),
    (message_id("ATTITUDE"), -5, mavlink2.MAV_RESULT_DENIED),
])
def test_set_message_interval_answers(msg_id, interval_us, result):
    proto = make_protocol()
    replies = proto.receive(from_gcs(command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id,
                                             interval_us)), 0.0, 0.0)
    ack = decoded(replies[0])
    assert (ack.get_type(), ack.command, ack.result) == (
        "COMMAND_ACK", mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, result)
    assert (ack.target_system, ack.target_component) == (255, 190)
    expected_hz = {20_000: 50.0, -1: 0.0, 0: 10.0}
    if result == mavlink2.MAV_RESULT_ACCEPTED:
        assert proto.schedule.rate_hz("ATTITUDE") == expected_hz[interval_us]


def test_get_interval_request_message_and_capabilities():
    proto = make_protocol()
    ack, interval = proto.receive(from_gcs(command(mavlink2.MAV_CMD_GET_MESSAGE_INTERVAL,
                                                   message_id("ATTITUDE"))), 0.0, 0.0)
    assert decoded(interval).interval_us == 100_000
    ack, = proto.receive(from_gcs(command(mavlink2.MAV_CMD_REQUEST_MESSAGE,
                                          message_id("HOME_POSITION"))), 0.0, 0.0)
    assert decoded(ack).result == mavlink2.MAV_RESULT_ACCEPTED
    assert proto.schedule.due(0.0)[0] == "HOME_POSITION"
    ack, version = proto.receive(from_gcs(command(mavlink2.MAV_CMD_REQUEST_MESSAGE,
                                                  message_id("AUTOPILOT_VERSION"))), 0, 0)
    assert decoded(version).capabilities & mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    ack, = proto.receive(from_gcs(command(mavlink2.MAV_CMD_REQUEST_MESSAGE,
                                          message_id("VFR_HUD"))), 0.0, 0.0)
    assert decoded(ack).result == mavlink2.MAV_RESULT_UNSUPPORTED
    ack, = proto.receive(from_gcs(command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)), 0, 0)
    assert decoded(ack).result == mavlink2.MAV_RESULT_UNSUPPORTED
    # addressed to the gimbal component or another system: not ours to answer
    assert proto.receive(from_gcs(command(mavlink2.MAV_CMD_REQUEST_MESSAGE, 30,
                                          target=(1, 154))), 0, 0) == []
    assert proto.receive(from_gcs(command(mavlink2.MAV_CMD_REQUEST_MESSAGE, 30,
                                          target=(2, 1))), 0, 0) == []


def test_params_by_name_index_and_list():
    proto = make_protocol()
    read = GCS.param_request_read_encode(1, 1, b"MNT1_PITCH_MIN", -1)
    value, = proto.receive(from_gcs(read), 0, 0)
    value = decoded(value)
    assert (value.param_id, value.param_value, value.param_index, value.param_count) == (
        "MNT1_PITCH_MIN", -90.0, 1, 3)
    value, = proto.receive(from_gcs(GCS.param_request_read_encode(1, 1, b"", 2)), 0, 0)
    assert decoded(value).param_id == "MNT1_PITCH_MAX"
    assert proto.receive(from_gcs(GCS.param_request_read_encode(1, 1, b"NOPE", -1)), 0, 0) == []
    assert proto.receive(from_gcs(GCS.param_request_read_encode(1, 1, b"", 3)), 0, 0) == []
    listed = proto.receive(from_gcs(GCS.param_request_list_encode(1, 1)), 0, 0)
    assert [decoded(m).param_id for m in listed] == ["MNT1_TYPE", "MNT1_PITCH_MIN",
                                                     "MNT1_PITCH_MAX"]
    value, = proto.receive(from_gcs(GCS.param_set_encode(1, 1, b"MNT1_TYPE", 7.0, 9)), 0, 0)
    assert decoded(value).param_value == 7.0 and proto.params["MNT1_TYPE"] == 7.0


def run_upload(proto, items, feed="whole", drop_every=0, t_step_s=0.05, t_end_s=60.0):
    """Upload ``items`` with pdcov's MissionUpload, the vehicle side parsing bytes."""
    gcs_parser = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    veh_parser = mavlink2.MAVLink(None, srcSystem=1)
    veh_parser.robust_parsing = True
    veh_mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    upload = MissionUpload(tuple(items), 1, 1, GCS, retry_s=1.0)
    to_vehicle = upload.start(0.0)
    n_sent = 0
    t = 0.0
    while upload.result is None and t < t_end_s:
        data = b""
        for m in to_vehicle:
            n_sent += 1
            if drop_every and n_sent % drop_every == 0:
                continue  # lost on the link
            data += bytes(m.pack(GCS))
        if feed == "junk":
            data = b"\x00\x07junk\r\n" + data + b"\x55\xaa"  # no magic byte: no packet eaten
        chunks = [data[i:i + 1] for i in range(len(data))] if feed == "bytes" else [data]
        replies = []
        for chunk in chunks:
            for msg in veh_parser.parse_buffer(chunk) or []:
                if msg.get_type() != "BAD_DATA":
                    replies += proto.receive(msg, t, t)
        replies += proto.poll(t)
        to_vehicle = []
        for r in replies:
            msg = gcs_parser.decode(bytearray(r.pack(veh_mav)))
            to_vehicle += upload.receive(msg, t)
        t += t_step_s
        to_vehicle += upload.poll(t)
    return upload.result


@pytest.mark.parametrize("feed", ["whole", "bytes", "junk"])
@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_mission_upload_with_pdcov_uploader(autopilot, feed):
    proto = make_protocol(autopilot)
    items = (home_item(ORIGIN), *mission_items(PLAN, ORIGIN))
    result = run_upload(proto, items, feed)
    assert result is not None and result.accepted, result
    got = proto.missions.mission
    assert [(g.command, g.frame) for g in got] == [(i.command, i.frame) for i in items]
    # PX4 asks with MISSION_REQUEST_INT, ArduPilot with MISSION_REQUEST; pdcov's uploader
    # answers both with MISSION_ITEM_INT (integer degE7): to 1e-7 deg
    tol = 1e-7
    for g, i in zip(got, items, strict=True):
        assert g.lat_deg == pytest.approx(i.lat_deg, abs=tol)
        assert g.lon_deg == pytest.approx(i.lon_deg, abs=tol)
        assert g.z_m == pytest.approx(i.z_m, abs=1e-4)
        assert g.param1 == pytest.approx(i.param1)


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_an_uploaded_gimbal_lock_reaches_the_simulator(autopilot):
    """A DO_GIMBAL_MANAGER_PITCHYAW with YAW_LOCK (param5 16) and a NAV_LOITER_TIME hover,
    uploaded as MISSION_ITEM_INT (x = param5 itself), arrive as written and fly locked."""
    from pdcov.core.mission import HoverItem
    from pdcov.planning.plan import GimbalPointing
    from pdcov_sitl.mission import flight_plan_from_items

    aim = GimbalPointing(-0.8, 2.0, earth_yaw=True)
    plan = Plan((Waypoint(0.0, 0.0, 10.0, 5.0, gimbal=GimbalPointing(-1.5)),
                 Waypoint(0.0, 40.0, 10.0, 5.0, 3.0, gimbal=aim)),
                hover_item=HoverItem.LOITER_TIME)
    items = mission_items(plan, ORIGIN)
    proto = make_protocol(autopilot)
    result = run_upload(proto, items)
    assert result is not None and result.accepted, result
    got = proto.missions.mission
    assert [(g.command, g.lat_deg) for g in got if g.command == 1000] == [(1000, 0.0),
                                                                       (1000, 16.0)]
    legs = flight_plan_from_items(tuple(got), ORIGIN, "uploaded").survey_legs
    assert [(leg.gimbal_earth_yaw, leg.hover_s) for leg in legs] == [(False, 0.0), (True, 3.0)]
    assert legs[1].gimbal_yaw_rad == pytest.approx(2.0, abs=1e-6)


def test_mission_upload_survives_lost_messages():
    proto = make_protocol("px4")
    items = mission_items(PLAN, ORIGIN)
    result = run_upload(proto, items, drop_every=3)
    assert result is not None and result.accepted
    assert len(proto.missions.mission) == len(items)


def test_mission_upload_times_out_when_the_client_goes_silent():
    proto = make_protocol("px4")
    count = from_gcs(GCS.mission_count_encode(1, 1, 3, 0))
    request, = proto.receive(count, 0.0, 100.0)
    assert decoded(request).get_type() == "MISSION_REQUEST_INT" and decoded(request).seq == 0
    assert proto.poll(101.0) == []
    resends = [proto.poll(100.0 + 1.6 * k) for k in range(1, 6)]
    assert all(decoded(r[0]).get_type() == "MISSION_REQUEST_INT" for r in resends)
    ack, = proto.poll(100.0 + 1.6 * 6)
    assert decoded(ack).type == mavlink2.MAV_MISSION_OPERATION_CANCELLED
    assert proto.missions.mission is None and not proto.missions.uploading


def test_second_client_is_refused_while_an_upload_runs():
    proto = make_protocol("px4")
    proto.receive(from_gcs(GCS.mission_count_encode(1, 1, 3, 0)), 0, 0)
    other = mavlink2.MAVLink(None, srcSystem=254, srcComponent=190)
    ack, = proto.receive(decoded_from(other, other.mission_count_encode(1, 1, 2, 0)), 0, 0)
    assert decoded(ack).type == mavlink2.MAV_MISSION_DENIED


def test_mission_download_reads_back_what_was_uploaded():
    proto = make_protocol("px4")
    items = mission_items(PLAN, ORIGIN)
    assert run_upload(proto, items).accepted
    count, = proto.receive(from_gcs(GCS.mission_request_list_encode(1, 1, 0)), 0, 0)
    assert decoded(count).count == len(items)
    for seq, it in enumerate(items):
        msg, = proto.receive(from_gcs(GCS.mission_request_int_encode(1, 1, seq, 0)), 0, 0)
        msg = decoded(msg)
        assert (msg.seq, msg.command, msg.x, msg.y) == (seq, it.command,
                                                        round(it.lat_deg * 1e7),
                                                        round(it.lon_deg * 1e7))
    bad, = proto.receive(from_gcs(GCS.mission_request_int_encode(1, 1, 99, 0)), 0, 0)
    assert decoded(bad).type == mavlink2.MAV_MISSION_INVALID_SEQUENCE
    fence, = proto.receive(from_gcs(GCS.mission_request_list_encode(1, 1, 1)), 0, 0)
    assert (decoded(fence).count, decoded(fence).mission_type) == (0, 1)
    ack, = proto.receive(from_gcs(GCS.mission_clear_all_encode(1, 1, 0)), 0, 0)
    assert decoded(ack).type == mavlink2.MAV_MISSION_ACCEPTED and proto.missions.mission == []


def test_protocol_rejects_bad_construction():
    with pytest.raises(ValueError, match="inav"):
        make_protocol("inav")
    with pytest.raises(ValueError, match="MNT1_TYPE_TOO_LONG_NAME"):
        make_protocol(params={"MNT1_TYPE_TOO_LONG_NAME": 1.0})
