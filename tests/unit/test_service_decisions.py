"""The daemon's decisions without I/O (STYLE.md "the daemon as aioquic does it"): MAVLink
messages and time stepped in memory into LinkProtocol and LiveCoverage."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.bus.tiles import decode_tiles
from pdcov.service.coverage import LiveCoverage
from pdcov.telemetry.link_protocol import (
    MAV_CMD_SET_MESSAGE_INTERVAL,
    MAV_COMP_ID_ONBOARD_COMPUTER,
    LinkProtocol,
)
from pdcov.telemetry.samples import AttitudeSample
from tests.support.service_feed import feed, serve_cfg


class _Sink:
    def write(self, b):
        pass


def autopilot(sysid=7):
    return mavlink.MAVLink(_Sink(), srcSystem=sysid, srcComponent=1)


def parsed(msg, mav):
    """A message as the daemon receives it: packed by ``mav`` and parsed back."""
    buf = msg.pack(mav)
    return mavlink.MAVLink(_Sink()).parse_buffer(buf)[0]


def heartbeat(mav, armed=False, autopilot_type=3, vtype=2):
    return parsed(mav.heartbeat_encode(vtype, autopilot_type, 128 if armed else 0, 0, 4), mav)


def test_link_follows_the_autopilot_and_never_sends_as_255():
    proto = LinkProtocol(mavlink.MAVLink(_Sink()), system_id=None,
                         intervals={30: 25.0, 33: 10.0}, param_names=(), param_timeout_s=2)
    gcs = mavlink.MAVLink(_Sink(), srcSystem=255, srcComponent=190)
    proto.receive(heartbeat(gcs, autopilot_type=8, vtype=6), 0.0)
    assert not proto.autopilot_known and proto.poll(0.0) == []
    ap = autopilot(7)
    proto.receive(heartbeat(ap), 0.1)
    out = proto.poll(0.1)
    names = [m.get_type() for m in out]
    assert names.count("COMMAND_LONG") == 3  # two intervals + HOME_POSITION request
    for m in out:
        buf = m.pack(proto.mav)
        back = mavlink.MAVLink(_Sink()).parse_buffer(buf)[0]
        assert (back.get_srcSystem(), back.get_srcComponent()) == (7,
                                                                    MAV_COMP_ID_ONBOARD_COMPUTER)
    # Refused: no retry (the autopilot's SRx_/MAVn_ rates must deliver); unanswered: 4 tries.
    ack = ap.command_ack_encode(MAV_CMD_SET_MESSAGE_INTERVAL, 4)  # MAV_RESULT_DENIED
    proto.receive(parsed(ack, ap), 0.2)
    sent = 0
    for k in range(1, 10):
        sent += sum(1 for m in proto.poll(0.1 + k * 1.01) if m.get_type() == "COMMAND_LONG"
                    and m.command == MAV_CMD_SET_MESSAGE_INTERVAL)
    results = {mid: r.result for mid, r in proto.interval_requests.items()}
    assert results == {30: "refused", 33: "unanswered"} and sent == 3
    with pytest.raises(RuntimeError, match="never sends"):
        proto.checked([proto.mav.command_long_encode(7, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)])  # ARM


def test_link_rerequests_after_a_reboot_and_reads_params():
    proto = LinkProtocol(mavlink.MAVLink(_Sink()), system_id=7, intervals={30: 25.0},
                         param_names=("MNT1_TYPE",), param_timeout_s=3.0)
    ap = autopilot(7)
    proto.receive(heartbeat(ap), 0.0)
    out = proto.poll(0.0)
    assert any(m.get_type() == "PARAM_REQUEST_READ" for m in out)
    proto.receive(parsed(ap.param_value_encode(b"MNT1_TYPE", 1.0, 9, 100, 3), ap), 0.5)
    assert proto.params_done and proto.params == {"MNT1_TYPE": 1.0}
    proto.receive(parsed(ap.command_ack_encode(MAV_CMD_SET_MESSAGE_INTERVAL, 0), ap), 0.6)
    assert proto.interval_requests[30].result == "acked"
    for t_ms in (100_000, 101_000, 2_000):  # time_boot_ms falls back: a reboot
        proto.receive(parsed(ap.attitude_encode(t_ms, 0, 0, 0, 0, 0, 0), ap), 1.0)
    assert proto.reboots == 1 and proto.interval_requests[30].result == "pending"
    assert any(m.get_type() == "COMMAND_LONG" for m in proto.poll(1.1))


def test_a_gimbal_heartbeat_before_the_autopilots_is_held_once():
    # A gimbal (own component, MAV_AUTOPILOT_INVALID) that speaks first: its HEARTBEAT waits
    # for the autopilot's like every other early message, is handled once, and the clock
    # knows the autopilot's component (it was built with None for good).
    proto = LinkProtocol(mavlink.MAVLink(_Sink()), system_id=7, intervals={},
                         param_names=(), param_timeout_s=2)
    gimbal = mavlink.MAVLink(_Sink(), srcSystem=7, srcComponent=154)
    assert proto.receive(heartbeat(gimbal, autopilot_type=8, vtype=26), 0.0) == []
    assert proto.stats.messages == 0
    ap = autopilot(7)
    proto.receive(heartbeat(ap), 0.1)
    assert proto.autopilot_component == 1 and proto.stats.messages == 2
    samples = proto.receive(parsed(ap.attitude_encode(5_000, 0.1, 0, 0, 0, 0, 0), ap), 0.2)
    assert [type(s) for s in samples] == [AttitudeSample]
    assert proto._clock is not None and proto._clock.autopilot_component == 1
    assert samples[0].t_s == pytest.approx(5.0)


def test_frames_skip_gaps_and_wait_for_telemetry():
    live = LiveCoverage(serve_cfg(), serve_cfg().mission.new_mission_grid(), 0.0)
    feed(live, 0.0, 10.0, skip=[(4.0, 6.5)])
    live.process()
    # 0..10 s at 5 Hz: 51 frames; those bracketed by the 2.6 s gap (> max_gap_s 1 s) skip.
    assert live.counters.used + sum(live.counters.skipped.values()) == 51
    assert live.counters.skipped["attitude gap"] == 13  # 4.0, 4.2, .., 6.4 s
    assert live.frames_pending == 0
    feed(live, 10.1, 10.25)  # a frame at 10.2 s, none at 10.4 s yet
    live.process()
    assert live.counters.used == 38 + 1 and live.last_frame_t_s == pytest.approx(10.2)


def test_tiles_stay_within_the_byte_budget_and_statustext_fires_once():
    cfg = serve_cfg()
    live = LiveCoverage(cfg, cfg.mission.new_mission_grid(), 0.0)
    feed(live, 0.0, 30.0)
    live.process()
    sent, texts, now = 0, [], 0.0
    changed_tiles = set()
    while now < 10.0:
        due = live.poll(now)
        if due.tiles:
            sent += len(due.tiles)
            changed_tiles |= {(t.tile_row, t.tile_col) for t in decode_tiles(due.tiles).tiles}
        if due.statustext:
            texts.append(due.statustext)
        now += 0.05
    assert sent <= 4096 * (10.0 + 1.0)  # rate x time + one second of burst
    assert changed_tiles == {(r, c) for r in range(4) for c in (0, 1)}  # all: 32 x 64 cells
    assert len(texts) == len(set(texts)) >= 1
    assert live.poll(now + 20).checkpoint  # frames since the last checkpoint
    live.checkpointed(live.grid.frames)
    assert not live.poll(now + 40).checkpoint
    assert math.isfinite(live.share_at_target())
