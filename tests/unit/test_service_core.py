"""ServiceCore in memory, time stepped (STYLE.md "the daemon as aioquic does it"): the
decisions the daemon shell used to make, each fed events and ``now_s`` with no loop, socket,
Zenoh or clock."""

from __future__ import annotations

import logging
import math
from pathlib import Path

import pytest
import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.bus.frames import encode_frames, encode_frames_v2
from pdcov.bus.tiled_snapshot import decode_grid_snapshot, encode_grid_snapshot
from pdcov.core.detections import Box, FrameBoxes
from pdcov.core.mount import GimbalMount
from pdcov.errors import InputFileError
from pdcov.service.checkpoint import read_checkpoint_meta, write_checkpoint
from pdcov.service.checkpoint_meta import CheckpointMeta
from pdcov.service.core import EARLY_FRAMES, LinkReport, ServiceCore, link_requests, link_state
from pdcov.service.detections import DETECTIONS_PERIOD_S
from pdcov.service.settings import load_serve_config
from pdcov.telemetry.frame_policy import FrameLattice
from pdcov.telemetry.gimbal import mount_params_complete, resolve_interpretation
from pdcov.telemetry.link_protocol import LinkState
from pdcov.telemetry.recorded_frames import MARK, recorded_mark
from tests.support.detections_driver import Driver
from tests.support.link_feed import FIXED, MISSION, Hover, pack


def core_of(tmp: Path, *, gimbal: bool = False, **service) -> ServiceCore:
    doc = dict(MISSION, mount=MISSION["mount"] if gimbal else FIXED)
    doc["service"] = {"state_dir": str(tmp / "state"), "reorder_s": 0.0, **service}
    (tmp / "m.yaml").write_text(yaml.safe_dump(doc))
    cfg = load_serve_config(tmp / "m.yaml")
    return ServiceCore(cfg, cfg.mission.new_mission_grid(), 0.0, mission_hash="h")


def test_a_grid_larger_than_a_grid_npz_carries_is_answered_tiled(tmp_path):
    """16.8 M cells, more than a grid.npz snapshot carries (MAX_CELLS, 16 M): the snapshot
    query is answered with the tiled snapshot, which a watcher decodes to the same grid."""
    side = 4100
    doc = dict(MISSION, mount=FIXED, domain={
        "polygon_enu_m": [[0, 0], [side, 0], [side, side], [0, side]], "cell_size_m": 1.0})
    doc["service"] = {"state_dir": str(tmp_path / "state")}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    cfg = load_serve_config(tmp_path / "m.yaml")
    core = ServiceCore(cfg, cfg.mission.new_mission_grid(), 0.0, mission_hash="h")
    assert core.admit_snapshot("a", 0.0) is None
    live = core.coverage
    payload = encode_grid_snapshot(live.grid, live.tile_size, live.grid_hash)
    assert payload[:4] == b"PDSS" and len(payload) < 1000  # no tile written yet
    state = decode_grid_snapshot(payload)
    assert state.hash == live.grid_hash and state.n_free == side * side
    (tmp_path / "small").mkdir()
    small = core_of(tmp_path / "small").coverage
    assert encode_grid_snapshot(small.grid, small.tile_size, small.grid_hash)[:2] == b"PK"


def parsed(data: bytes) -> list:
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    return parser.parse_buffer(data) or []


def test_early_detector_frames_wait_for_the_autopilot_then_are_taken_and_recorded(tmp_path):
    core = core_of(tmp_path, frame_source="zenoh")
    core.receive_frames(encode_frames([1.2, 1.4, 5e6]))  # 5e6 s: past time_boot_ms's range
    assert core.coverage.counters.faults["frames_out_of_range"] == 1
    assert core.actions().record == []  # held: no autopilot, no clock yet
    msgs = [m for i, msg in enumerate(Hover(seconds=2.0).messages())
            for m in parsed(pack(msg, seq=i))]
    core.receive_mavlink(msgs, 0.5)
    core.process()
    records = core.actions().record
    marks = [m for data in records for m in parsed(data) if recorded_mark(m) == MARK]
    assert [m.time_boot_ms for m in marks] == [1200, 1400]
    assert len(records) == len(msgs) + 2  # every message, then the frames taken
    core.receive_frames(b"not json")
    assert core.coverage.counters.faults["bad_frames_messages"] == 1
    assert core.actions().logs[0][0] == logging.WARNING


def test_early_frames_are_bounded(tmp_path):
    core = core_of(tmp_path, frame_source="zenoh", record=False)
    for k in range(EARLY_FRAMES // 1000 + 1):
        core.receive_frames(encode_frames([0.001 * (1000 * k + j) for j in range(1000)]))
    assert core.coverage.counters.faults["frames_dropped_waiting"] == 1000


def test_bad_data_is_counted_once_and_reported(tmp_path):
    core = core_of(tmp_path, record=False)
    core.receive_mavlink(parsed(b"\xfd\x09garbage-not-mavlink" * 3), 0.0)
    fields, _line = core.status(0.0, LinkReport(parse_errors=2))
    bad = core.protocol.stats.bad
    assert bad > 0 and fields["link"]["bad_messages"] == fields["faults"]["bad_messages"] == bad
    assert fields["faults"]["link_parse_errors"] == 2


def test_timer_status_and_kernel_drop_warning_rate_limit(tmp_path):
    core = core_of(tmp_path, record=False)
    assert core.get_timer() == 0.0  # status, tiles and values due at once
    core.tick(0.0, 0.0)
    assert core.actions().status_due
    assert core.get_timer() > 0.0
    warnings = []
    now = 0.0
    for drops in (0, 5, 9, 12):
        _fields, _ = core.status(now, LinkReport(kernel_drops=drops))
        warnings += [t for _lv, t in core.actions().logs if "kernel dropped" in t]
        now += 30.0  # a warning at most once a minute, while the count grows
    assert len(warnings) == 2 and "dropped 5 " in warnings[0] and "dropped 12 " in warnings[1]


def test_checkpoint_errors_are_logged_once_and_the_recovery_once(tmp_path):
    core = core_of(tmp_path, record=False)
    meta = core.checkpoint_meta(1_700_000_000.0)
    assert meta.mission_hash == "h" and meta.last_frame_t_s is None and meta.clock_boot_s is None
    for _ in range(3):
        core.checkpoint_written(meta, "No space left on device", core.checkpoint_contents())
    logs = core.actions().logs
    assert [lv for lv, _t in logs] == [logging.ERROR]
    assert core.coverage.counters.faults["checkpoint_errors"] == 3
    assert core.checkpoint.describe()["error"] == "No space left on device"
    core.checkpoint_written(meta, None, core.checkpoint_contents())
    (level, text), = core.actions().logs
    assert level == logging.WARNING and "written again" in text
    info = core.checkpoint.describe()
    assert info["error"] is None and info["written_unix_s"] == 1_700_000_000.0


def test_a_journal_line_after_a_checkpoint_was_copied_is_kept_when_it_is_written(tmp_path):
    """A checkpoint copied at journal line 1 and written after line 2 was decided (a second
    checkpoint decided meanwhile) must not empty the journal: line 2 is in neither file
    otherwise. The journal is emptied when the checkpoint holding line 2 is written."""
    doc = dict(MISSION, mount=FIXED, vehicle_id="uav7")
    doc["service"] = {"state_dir": str(tmp_path / "state"), "frame_source": "zenoh",
                      "reorder_s": 0.0}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    d = Driver(tmp_path / "m.yaml", tmp_path / "rec")
    d.link(b"".join(pack(m, seq=i) for i, m in enumerate(Hover(seconds=4.0).messages())))
    person = Box("person", 0.9, 310.0, 200.0, 18.0, 40.0)

    def publish(t0_s: float) -> None:
        d.frames(encode_frames_v2([FrameBoxes(t0_s + 0.2 * k, (person,)) for k in range(3)]))
        d.core.process()
        d.tick(DETECTIONS_PERIOD_S)

    publish(2.0)
    first = d.core.checkpoint_contents()
    meta = d.core.checkpoint_meta(1_700_000_000.0)
    publish(3.0)
    second = d.core.checkpoint_contents()
    assert first.journal_seq == 1 and second.journal_seq == 2
    assert first.frames < second.frames
    d.core.checkpoint_written(meta, None, first)
    assert not d.core.actions().journal_reset
    assert d.core.checkpoint.frames == first.frames
    d.core.checkpoint_written(meta, None, second)
    assert d.core.actions().journal_reset


def test_checkpoint_meta_round_trips_and_refuses_what_pdcov_does_not_write(tmp_path):
    core = core_of(tmp_path, record=False)
    grid = core.coverage.grid
    meta = CheckpointMeta("h", "uav1", t0_s=1.5, last_frame_t_s=9.25, clock_offset_s=64.0,
                          clock_boot_s=3.0, tiles_seq=7, frames_used=12, written_unix_s=1.0)
    write_checkpoint(tmp_path / "c.npz", grid, meta)
    assert read_checkpoint_meta(tmp_path / "c.npz") == meta
    write_checkpoint(tmp_path / "bad.npz", grid, {"mission_hash": "h", "clock": [1.0, "x"]})
    with pytest.raises(InputFileError, match="clock"):
        read_checkpoint_meta(tmp_path / "bad.npz")


def test_a_resumed_core_continues_lattice_clock_and_counts(tmp_path):
    first = core_of(tmp_path, record=False)
    cfg = first.cfg
    meta = CheckpointMeta("h", "uav1", t0_s=1.0, last_frame_t_s=3.0, clock_offset_s=70.0,
                          clock_boot_s=4.0, tiles_seq=41, frames_used=11)
    core = ServiceCore(cfg, cfg.mission.new_mission_grid(), 0.0, mission_hash="h", resumed=meta)
    live = core.coverage
    assert live.tiles_seq == 42 and live.counters.used == 11
    assert live.lattice == FrameLattice(1.0, cfg.mission.first_camera.frame_rate_hz)
    assert live.last_frame_t_s == 3.0
    assert core.protocol._primed == (70.0, 4.0)


@pytest.mark.parametrize(("states", "known", "state"), [
    ((), False, LinkState.NONE),
    ((LinkState.CONNECTING,), False, LinkState.CONNECTING),
    ((LinkState.CONNECTED, LinkState.LOST), False, LinkState.WAITING),
    ((LinkState.LOST, LinkState.CONNECTED), True, LinkState.CONNECTED),
    ((LinkState.LOST, LinkState.WAITING), True, LinkState.WAITING),
])
def test_link_state(states, known, state):
    assert link_state(states, known) == state == str(state)


def test_the_daemon_asks_for_the_mount_parameters_mount_check_reads(tmp_path):
    core = core_of(tmp_path, gimbal=True, record=False)
    _intervals, names, complete = link_requests(core.cfg)
    assert {"MNT1_TYPE", "MNT2_TYPE", "MNT1_PITCH_MIN", "MNT_TYPE",
            "MNT_ANGMIN_TIL"} <= set(names)
    assert complete is not None
    legacy = {n: 0.0 for n in names if not n.startswith(("MNT1_", "MNT2_"))}
    assert complete(legacy) and mount_params_complete(legacy, 1)
    assert not complete({"MNT_TYPE": 1.0})
    # An ArduPilot 4.2 servo mount, answered by its legacy names: the link takes it as done.
    proto = core.protocol
    ap = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    msgs = parsed(ap.heartbeat_encode(2, 3, 0, 0, 4).pack(ap))
    for n in legacy:
        msgs += parsed(ap.param_value_encode(n.encode(), 1.0 if n == "MNT_TYPE" else 0.0, 9,
                                             len(legacy), 0).pack(ap))
    core.receive_mavlink(msgs, 0.0)
    assert proto.params_done and proto.param_request.result == "acked"


def test_a_brushless_pwm_mount_is_said_to_report_its_earth_frame_demand():
    interp = resolve_interpretation(GimbalMount(attitude_frame="auto"), {"MNT1_TYPE": 7.0},
                                    "the test")
    assert interp.frame == "flags"
    assert "BrushlessPWM mount reports its earth-frame demand" in interp.reason
    assert "reports its attitude" not in interp.reason


def test_frame_lattice_is_the_offline_frame_times():
    lattice = FrameLattice(12.345, 7.0)
    n = lattice.count_until(99.9)
    t = lattice.times(n)
    assert [lattice.t(k) for k in range(n)] == t.tolist()
    assert t[-1] <= 99.9 < lattice.t(n)
    assert lattice.first_at_or_after(float(t[5]) + 1e-6) == 6
    assert math.isclose(lattice.t(lattice.first_at_or_after(50.0)), 50.0, abs_tol=1 / 7)
