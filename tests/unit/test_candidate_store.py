"""Candidates across restarts (service/candidate_store.py, issue 35): the tracker's state
round trip, the journal's rules (a line per publish before it, emptied after a checkpoint,
a torn last line, a bad line, the cap), the checkpoint's member, and a daemon stopped
cleanly or killed and started again on its state directory. In memory: the daemon's shell
(``Daemon``, no loop) fed a hover's MAVLink and a detector's frames."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from pdcov.bus.detections import decode_detections
from pdcov.bus.frames import encode_frames_v2
from pdcov.config.load import load_mission
from pdcov.core.camera import CameraModel
from pdcov.core.detections import Box, FrameBoxes
from pdcov.core.geolocate import Geolocation
from pdcov.core.pose import FixedMount, fixed_mount_pose
from pdcov.detection.candidates import DetectionTracker
from pdcov.errors import ConfigError
from pdcov.ids import candidate_uid_prefix, valid_epoch
from pdcov.service import candidate_store
from pdcov.service.candidate_store import JOURNAL_NAME, checkpoint_doc, journal_line, restore
from pdcov.service.checkpoint import (
    CANDIDATES_FILE,
    CHECKPOINT_NAME,
    current_slot,
    resume,
    write_checkpoint,
)
from pdcov.service.checkpoint_meta import CheckpointMeta
from pdcov.service.daemon import Daemon
from pdcov.service.detections import DETECTIONS_PERIOD_S
from pdcov.service.settings import load_serve_config
from pdcov.service.state_files import EPOCH_NAME
from pdcov.telemetry.tlog import mavlink
from tests.support.link_feed import FIXED, MISSION, Hover, pack

CAMERA = CameraModel.from_fov(640, 480, 90.0)  # f = 320 px: 16 px per m at 20 m
DEMO = Path(__file__).resolve().parents[2] / "service/pdcov/data/demo_mission.yaml"


def tracker() -> DetectionTracker:
    return DetectionTracker(CAMERA, Geolocation(roll_sigma_rad=0, pitch_sigma_rad=0,
                                                yaw_sigma_rad=0, horizontal_sigma_m=0,
                                                vertical_sigma_m=0, pixel_sigma_px=1.6), 1.0,
                            uid_prefix="uav1.a1b2c3.")


def at(x_m: float, cls: str = "person") -> Box:
    """A 10 x 10 px box over the ground point x_m east of a nadir camera at 20 m."""
    return Box(cls, 0.9, 319.5 + 16 * x_m - 5, 234.5, 10, 10)


def nadir():
    return fixed_mount_pose(np.eye(3), np.array([0.0, 0.0, 20.0]), FixedMount())


def three() -> DetectionTracker:
    """Candidates 0 (two hits at 0 m), 1 (5 m) and 2 (a car at 0 m)."""
    t = tracker()
    t.frame(nadir(), 1.0, [at(0.0), at(5.0), at(0.0, "car")])
    t.frame(nadir(), 1.2, [at(0.0)])
    return t


def as_tuples(t: DetectionTracker, grid) -> list[tuple]:
    return [(c.candidate_id, c.uid, c.class_name, *c.r_enu_m.round(9), c.sigma_m, c.hits,
             c.first_t_boot_s, c.last_t_boot_s) for c in t.candidates(grid)]


@pytest.fixture(scope="module")
def grid():
    return load_mission(DEMO).new_mission_grid()


# --- the tracker's state ----------------------------------------------------------------------

def test_the_tracker_state_round_trips_and_its_ids_continue(grid):
    t = three()
    again = tracker()
    again.load_doc(json.loads(json.dumps(t.to_doc())))
    assert as_tuples(again, grid) == as_tuples(t, grid)
    assert [c.uid for c in again.candidates(grid)] == [
        "uav1.a1b2c3.0", "uav1.a1b2c3.1", "uav1.a1b2c3.2"]
    assert again.next_id == 3
    # Candidate 0 at 0 m takes a box 0.2 m off (its gate: 3 hypot(0.1, 0.07) = 0.37 m); a
    # box 20 m off is candidate 3, never 0.
    d = again.frame(nadir(), 1.4, [at(0.2), at(20.0)])
    assert [x.candidate_id for x in d] == [0, 3]


@pytest.mark.parametrize(("field", "value", "named"), [
    ("sum_wr", [1.0, 2.0], "candidates[1].sum_wr"), ("hits", -1, "candidates[1].hits"),
    ("sum_w", 0.0, "candidates[1].sum_w"), ("class_name", "", "candidates[1].class_name"),
    ("id", 0, "candidates[1].id")])
def test_a_damaged_tracker_state_is_refused_naming_its_field(field, value, named):
    doc = three().to_doc()
    doc["candidates"][1][field] = value
    t = three()
    with pytest.raises(ValueError, match=named.replace("[", r"\[").replace("]", r"\]")):
        t.load_doc(doc)
    with pytest.raises(ValueError, match="next_id"):
        t.load_doc({**three().to_doc(), "next_id": 2})  # candidate 2 exists
    assert len(t) == 3 and t.next_id == 3  # unchanged


# --- the journal's rules ------------------------------------------------------------------------

def test_a_journal_line_holds_the_touched_candidates_and_the_next_id():
    t = three()
    line = journal_line(t, [2, 0, 7], 5, "h")
    assert line.endswith(b"\n") and line.count(b"\n") == 1
    doc = json.loads(line)
    assert (doc["seq"], doc["mission_hash"], doc["next_id"]) == (5, "h", 3)
    assert [c["id"] for c in doc["candidates"]] == [0, 2]  # 7: no such candidate
    assert doc["candidates"][0]["hits"] == 2


def restored(journal: bytes | None, checkpoint=None, **kw) -> tuple[DetectionTracker, object]:
    t = tracker()
    r = restore(t, "h", resumed=checkpoint is not None, checkpoint=checkpoint,
                checkpoint_error=kw.get("error"), checkpoint_path="ck.npz", journal=journal,
                journal_path="c.journal")
    return t, r


def lines() -> tuple[dict, bytes, bytes, DetectionTracker]:
    """A checkpoint (journal_seq 1) of three(), the line seq 1 it includes, and line 2:
    candidate 0 one more hit and candidate 3 new."""
    t = three()
    first = journal_line(t, [0], 1, "h")
    ck = checkpoint_doc(t, 1)
    t.frame(nadir(), 1.4, [at(0.0), at(-8.0)])
    return ck, first, journal_line(t, [0, 3], 2, "h"), t


def test_restore_is_the_checkpoint_then_the_lines_after_it(grid):
    ck, first, second, later = lines()
    t, r = restored(first + second, ck)
    assert as_tuples(t, grid) == as_tuples(later, grid)
    assert [c.hits for c in t.candidates(grid)] == [3, 1, 1, 1]
    # Line 1 is in the checkpoint (a kill before the journal was emptied): skipped.
    assert (r.from_checkpoint, r.candidates, r.from_journal, r.lines, r.journal_seq) == (
        3, 4, 2, 1, 2)
    assert t.next_id == 4 and r.keep_bytes == len(first + second) and not r.set_aside
    # Without a checkpoint (killed before the first): every line, in order.
    t, r = restored(first + second)
    assert [c.candidate_id for c in t.candidates(grid)] == [0, 3] and t.next_id == 4


def test_a_torn_last_line_is_ignored_and_cut_off(grid):
    ck, first, second, _later = lines()
    t, r = restored(first + second[:-9], ck)
    assert r.lines == 0 and r.keep_bytes == len(first) and not r.set_aside
    assert len(t) == 3 and t.next_id == 3
    [(level, text)] = r.logs
    assert level == logging.WARNING and "torn" in text and "c.journal" in text


@pytest.mark.parametrize(("bad", "why"), [
    (b"{not json\n", "not JSON"),
    (b'{"version": 1, "seq": 2, "mission_hash": "other", "next_id": 9, "candidates": []}\n',
     "mission hash 'other'"),
    (b'{"version": 1, "seq": 2, "mission_hash": "h", "next_id": 9, '
     b'"candidates": [{"id": 4, "class_name": "person"}]}\n', "docs[0].sum_w")])
def test_a_bad_line_stops_the_replay_and_sets_the_journal_aside(bad, why):
    ck, first, second, _later = lines()
    bad = bad.replace(b'"seq": 2', b'"seq": 3')
    second = second.replace(b'"seq":2', b'"seq":4')
    t, r = restored(first.replace(b'"seq":1', b'"seq":2') + bad + second, {**ck,
                                                                           "journal_seq": 0})
    assert r.lines == 1 and r.set_aside and len(t) == 3  # line 3 not applied
    [(level, text)] = r.logs
    assert level == logging.ERROR and "c.journal: line 2" in text and why in text, text


def test_a_journal_over_the_cap_is_refused_whole(monkeypatch):
    ck, first, second, _later = lines()
    monkeypatch.setattr(candidate_store, "MAX_JOURNAL_BYTES", len(first + second) - 1)
    t, r = restored(first + second, ck)
    assert r.set_aside and r.lines == 0 and len(t) == 3
    assert "over" in r.logs[0][1] and r.logs[0][0] == logging.ERROR


def test_a_damaged_checkpoint_member_starts_the_candidates_empty_the_journal_still_applies():
    ck, first, second, _later = lines()
    ck["tracker"]["candidates"][0]["hits"] = "many"
    t, r = restored(first + second, ck)
    (level, text), = r.logs
    assert level == logging.ERROR and "ck.npz: pdcov_candidates.json" in text
    assert "tracker.candidates state candidates[0].hits 'many'" in text
    assert r.from_checkpoint == 0 and r.lines == 2 and len(t) == 2  # 0 and 3, from lines
    t, r = restored(None, None)  # no checkpoint resumed: nothing said
    assert r.logs == [] and len(t) == 0


# --- the checkpoint's member --------------------------------------------------------------------

def test_the_checkpoint_carries_the_candidates_and_an_older_or_damaged_one_keeps_its_grid(
        tmp_path, grid):
    doc = checkpoint_doc(three(), 4)
    path = tmp_path / CHECKPOINT_NAME
    write_checkpoint(path, grid, CheckpointMeta("h", "uav1"), candidates=doc)
    r = resume(tmp_path, "h", load_mission(DEMO).new_mission_grid())
    assert r.grid is not None and r.candidates == doc and r.candidates_error is None
    write_checkpoint(path, grid, CheckpointMeta("h", "uav1"))  # older: no member
    r = resume(tmp_path, "h", load_mission(DEMO).new_mission_grid())
    assert r.grid is not None and r.candidates is None and r.candidates_error is None
    (current_slot(path) / CANDIDATES_FILE).write_bytes(b'{"version": 1, "journal_seq": ')
    r = resume(tmp_path, "h", load_mission(DEMO).new_mission_grid())
    assert r.grid is not None and r.candidates is None
    assert "JSONDecodeError" in (r.candidates_error or "")


# --- the daemon, stopped or killed and started again --------------------------------------------

def config(tmp: Path) -> Path:
    doc = dict(MISSION, mount=FIXED, vehicle_id="uav7")
    doc["service"] = {"state_dir": str(tmp / "state"), "frame_source": "zenoh",
                      "reorder_s": 0.0, "record": False, "checkpoint_period_s": 1e6}
    (tmp / "m.yaml").write_text(yaml.safe_dump(doc))
    return tmp / "m.yaml"


class Clock:
    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


def started(tmp: Path) -> tuple[Daemon, Clock]:
    clock = Clock()
    return Daemon(load_serve_config(config(tmp)), clock=clock), clock


def fly(d: Daemon, clock: Clock, frames: list[FrameBoxes], seconds: float = 2.0) -> None:
    """The hover's telemetry and ``frames`` into the daemon's core, then ticks a period
    apart (what the core says is done: journal, puts -- no session: counted --, logs).
    Without frames the grid takes none: the telemetry gives the origin's ground altitude
    (a restarted daemon answers candidates once it is known again)."""
    parser = mavlink.MAVLink(None)
    msgs = [m for i, msg in enumerate(Hover(seconds=seconds).messages())
            for m in parser.parse_buffer(pack(msg, seq=i)) or []]
    d.core.receive_mavlink(msgs, clock.now_s)
    if frames:
        d.core.receive_frames(encode_frames_v2(frames))
    d.core.process()
    for _ in range(3):
        clock.now_s += DETECTIONS_PERIOD_S
        d._tick()


def boxes(k: int) -> tuple[Box, ...]:
    """Frame k's: a person near the centre, one at the left edge, a car every other."""
    out = [Box("person", 0.8, 310.0 + k % 3, 200.0, 18.0, 40.0),
           Box("person", 0.6, 10.0, 300.0, 12.0, 30.0)]
    return (*out, Box("car", 0.7, 500.0, 100.0, 60.0, 30.0)) if k % 2 else tuple(out)


def candidates(d: Daemon) -> list[dict]:
    return decode_detections(d.core.candidates_payload())["candidates"]


def test_a_restart_keeps_every_candidate_its_id_and_uid(tmp_path, caplog):
    d, clock = started(tmp_path)
    state = tmp_path / "state"
    epoch = (state / EPOCH_NAME).read_text().strip()
    assert valid_epoch(epoch)
    fly(d, clock, [FrameBoxes(1.2 + 0.2 * k, boxes(k)) for k in range(12)], 4.0)
    before = candidates(d)
    assert len(before) == 3 and (state / JOURNAL_NAME).stat().st_size > 0
    tracked = d.live.detections.tracker.candidates(d.live.grid)
    assert [c.uid for c in tracked] == [f"uav7.{epoch}.{i}" for i in range(3)]
    # kill -9 now: no checkpoint holds them, the journal does.
    with caplog.at_level(logging.INFO, logger="pdcov.serve"):
        killed, _ = started(tmp_path)
    assert "candidates restored: 3 (0 from the checkpoint, 3 updated or added by 1 journal " \
        "lines)" in caplog.text
    assert len(killed.live.detections.latest) == 3  # the status's pins summary at once
    fly(killed, clock, [])
    # The grid restarts empty (no checkpoint): P_D and P_FA 0; the candidates keep their looks.
    assert candidates(killed) == [{**c, "pd": 0.0, "pfa": 0.0} for c in before]
    assert killed.live.detections.tracker.candidates(killed.live.grid)[2].uid == \
        f"uav7.{epoch}.2"
    info = killed.core.checkpoint.describe()
    assert (info["resumed"], info["candidates_restored"], info["candidates_from_journal"]) \
        == (False, 3, 3)
    # A clean stop: the final checkpoint holds them and the journal is emptied.
    d._shutdown()
    assert (state / JOURNAL_NAME).stat().st_size == 0
    again, _ = started(tmp_path)
    fly(again, clock, [])
    assert candidates(again) == before  # the same grid: the same looks, P_D, P_FA too
    info = again.core.checkpoint.describe()
    assert info["candidates_restored"] == 3 and info["candidates_from_journal"] == 0
    # New candidates continue the ids: a person far off is id 3.
    far = Box("person", 0.9, 600.0, 440.0, 12.0, 30.0)
    fly(again, clock, [FrameBoxes(4.2, (far,))], 5.0)
    assert [c["id"] for c in candidates(again)] == [0, 1, 2, 3]


def test_a_clean_stop_publishes_the_pending_detections_before_its_checkpoint(tmp_path):
    d, clock = started(tmp_path)
    fly(d, clock, [FrameBoxes(1.2, boxes(0))])  # published: candidates 0 and 1
    published: list[dict] = []
    d.bus.put = lambda pub, p: published.append(  # type: ignore[method-assign]
        decode_detections(p)) if b'"pdcov.detections"' in p else None
    for t_s in (1.4, 1.6):  # the first published at once, the second within the period
        d.core.receive_frames(encode_frames_v2([FrameBoxes(t_s, boxes(1))]))
        d.core.process()
        d._tick()
    assert len(published) == 1
    d._shutdown()
    assert len(published) == 2
    assert [x["t_boot_s"] for x in published[1]["detections"]] == [1.6] * 3
    again, _ = started(tmp_path)
    fly(again, clock, [])
    # Frames 1.2, 1.4 and 1.6 s fall in one look of the mission's (min_revisit_s 1 s): one hit
    # each, and every one of them came back.
    assert [c["hits"] for c in candidates(again)] == [1, 1, 1]


def test_a_torn_journal_line_is_cut_off_and_a_bad_epoch_refused(tmp_path, caplog):
    d, clock = started(tmp_path)
    fly(d, clock, [FrameBoxes(1.2, boxes(0))], 2.0)
    journal = tmp_path / "state" / JOURNAL_NAME
    whole = journal.read_bytes()
    with journal.open("ab") as f:
        f.write(b'{"version":1,"seq":2,"mission')
    with caplog.at_level(logging.WARNING, logger="pdcov.serve"):
        again, _ = started(tmp_path)
    fly(again, clock, [])
    assert len(candidates(again)) == 2 and journal.read_bytes() == whole
    assert any("torn" in r.getMessage() for r in caplog.records)
    (tmp_path / "state" / EPOCH_NAME).write_text("xyz\n")
    with pytest.raises(ConfigError, match="epoch"):
        started(tmp_path)


def test_the_journal_append_is_bounded_and_a_failed_one_counted(tmp_path, monkeypatch):
    import pdcov.service.core as core

    monkeypatch.setattr(core, "MAX_JOURNAL_BYTES", 100)
    d, clock = started(tmp_path)
    fly(d, clock, [FrameBoxes(1.2, boxes(0))], 2.0)
    assert not (tmp_path / "state" / JOURNAL_NAME).exists()  # the line would be > 100 B
    assert d.live.counters.faults["candidates_journal_errors"] == 1
    assert math.isfinite(clock.now_s)


def test_uid_prefix_rule():
    assert candidate_uid_prefix("uav-7", "0a1b2c") == "uav-7.0a1b2c."
    for vehicle, epoch in (("uav.7", "0a1b2c"), ("uav7", "0A1B2C"), ("uav7", "0a1b2")):
        with pytest.raises(ValueError, match="uid prefix"):
            candidate_uid_prefix(vehicle, epoch)


def test_an_offline_epoch_is_the_log_s_sha256(tmp_path):
    from pdcov.report.detections import log_epoch

    (tmp_path / "f.tlog").write_bytes(b"abc")  # SHA-256 ba7816bf 8f01cfea ...
    assert log_epoch(tmp_path / "f.tlog") == "ba7816"
