"""Live = offline for detections: a ``ServiceCore`` fed a hover's MAVLink bytes and a
detector's frames version 2 publishes detections, and answers candidates, exactly as
``pdcov evaluate`` of its recording writes them in detections.json; refused boxes are
counted by reason. In memory: the core, a real recorder, the real CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from pdcov.bus.detections import decode_detections
from pdcov.bus.frames import encode_frames, encode_frames_v2
from pdcov.cli import main as pdcov_main
from pdcov.core.detections import Box, FrameBoxes
from pdcov.service.core import LinkReport
from pdcov.service.detections import DETECTIONS_PERIOD_S
from tests.support.detections_driver import Driver
from tests.support.link_feed import FIXED, MISSION, Hover, pack, without_epoch


def _config(tmp: Path) -> Path:
    doc = dict(MISSION, mount=FIXED, vehicle_id="uav7")
    doc["service"] = {"state_dir": str(tmp / "state"), "frame_source": "zenoh",
                      "reorder_s": 0.0}
    (tmp / "m.yaml").write_text(yaml.safe_dump(doc))
    return tmp / "m.yaml"


def _boxes(k: int, rng: np.random.Generator) -> tuple[Box, ...]:
    """Frame k's boxes: a person near the picture's centre (pixel noise), a car to the
    right every other frame, and a person at the far left edge."""
    out = [Box("person", 0.8 + 0.01 * k, 310 + rng.normal(0, 1.5), 200 + rng.normal(0, 1.5),
               18.0, 40.0)]
    if k % 2:
        out.append(Box("car", 0.6, 500.0 + rng.normal(0, 1), 100.0, 60.0, 30.0))
    out.append(Box("person", 0.51, -0.5, 300.0, 12.0, 30.0))
    return tuple(out)


def test_published_detections_and_candidates_are_evaluate_s(tmp_path: Path) -> None:
    cfg_path = _config(tmp_path)
    d = Driver(cfg_path, tmp_path / "rec")
    msgs = [pack(m, seq=i) for i, m in enumerate(Hover(seconds=4.0).messages())]
    rng = np.random.default_rng(7)
    frames = [FrameBoxes(1.2 + 0.2 * k, _boxes(k, rng)) for k in range(16)]  # 1.2 .. 4.2 s
    d.frames(encode_frames_v2(frames[:2]))  # before any HEARTBEAT: held
    half = len(msgs) // 2
    d.link(b"".join(msgs[:half]))
    d.frames(encode_frames_v2(frames[2:8]))
    d.tick(0.3)
    outside = FrameBoxes(2.95, (Box("person", 0.9, 630.0, 0.0, 20.0, 20.0),))  # x to 649.5
    d.frames(encode_frames_v2([outside]))  # refused whole: counted
    d.frames(encode_frames_v2([FrameBoxes(2.97, (Box("person", 0.9, 0, 0, 5, 5),) * 257)]))
    d.frames(json.dumps({"schema": "pdcov.frames", "version": 2, "vehicle": "uav8",
                         "frames": [{"t_boot_s": 2.99, "boxes": []}]}).encode())
    d.link(b"".join(msgs[half:]))
    d.tick(0.3)
    d.frames(encode_frames_v2(frames[8:]))
    d.frames(encode_frames_v2([FrameBoxes(1.3, _boxes(0, rng))]))  # late: not taken
    d.frames(encode_frames([4.4, 4.6]))  # version 1 still read
    far = FrameBoxes(600.0, _boxes(1, rng))  # 596 s ahead of the autopilot's clock: refused
    d.frames(encode_frames_v2([far]))
    d.core.process()
    for _ in range(5):
        d.tick(DETECTIONS_PERIOD_S)
    d.recorder.close()

    faults = d.core.status(d.now_s, LinkReport())[0]["faults"]
    assert faults["bad_frames_messages"] == 3, faults
    assert faults["frames_refused_outside_picture"] == 1, faults
    assert faults["frames_refused_over_bound"] == 1, faults
    assert faults["frames_refused_bad_field"] == 1, faults  # another vehicle's
    assert faults["frames_refused_ahead_of_clock"] == 1, faults  # the far one
    assert faults["boxes_of_frames_not_taken"] == 2 + len(far.boxes), faults  # late, far
    live_candidates = decode_detections(d.core.candidates_payload())["candidates"]
    live_detections = [x for msg in d.published for x in msg["detections"]]
    used = d.core.coverage.counters.used
    assert used >= 16, used
    # Every box of the 16 frames, each frame used once: 3 or 2 boxes.
    assert len(live_detections) == sum(len(f.boxes) for f in frames)
    # The centre person, the car, the edge person: three candidates.
    by_id = {c["id"]: c for c in live_candidates}
    # Frames at 5 fps from 1.2 s to 4.2 s, a look a second (min_revisit_s 1): 4 looks of
    # each cell, each a hit (the car's box every other frame makes each look a hit too).
    assert sorted((c["class"], c["hits"], c["looks"]) for c in live_candidates) == [
        ("car", 4, 4), ("person", 4, 4), ("person", 4, 4)], live_candidates
    centre = next(c for c in live_candidates if c["class"] == "person"
                  and c["confidence"] > 0.9)
    grid = d.core.coverage.grid  # min_revisit_s 1: a look a second over the 4 s hover
    row, col = grid.geometry.cell_of(centre["x_m"], centre["y_m"])
    assert centre["looks"] == grid.n_obs[row, col] >= 3, centre
    assert centre["pd"] == grid.pd[row, col] > 0 and centre["pfa"] == grid.pfa[row, col]
    for msg in d.published:  # each message carries the candidates its detections touched
        assert {x["candidate"] for x in msg["detections"]} == {
            c["id"] for c in msg["candidates"]}
    assert set(by_id) == {x["candidate"] for x in live_detections}

    _offline_is_live(tmp_path, cfg_path, live_detections, live_candidates)


def _offline_is_live(tmp_path: Path, cfg_path: Path, detections: list[dict],
                     candidates: list[dict]) -> tuple[dict, Path]:
    """``pdcov evaluate`` of the daemon's recording: its detections.json is the live
    detections and candidates (but the uids' epochs); (that document, the run folder)."""
    rec = next((tmp_path / "rec").glob("flight-*.tlog"))
    out = tmp_path / "offline"
    assert pdcov_main(["evaluate", "--config", str(cfg_path), "--log", str(rec), "--out",
                       str(out), "--no-progress"]) == 0
    offline = decode_detections((out / "detections.json").read_bytes(), vehicle_id="uav7")
    assert without_epoch(offline["detections"]) == without_epoch(detections)
    assert without_epoch(offline["candidates"]) == without_epoch(candidates)
    return offline, out


def test_boxes_of_classes_the_model_does_not_name_and_frames_off_the_clock_are_refused(
        tmp_path: Path) -> None:
    """service/frame_admission.py through ServiceCore: a box of an invented class, a frame
    1e6 s ahead and one older than the tracker's history are counted, not taken."""
    from pdcov.core.detector import DetectorModel

    doc = yaml.safe_load(_config(tmp_path).read_text())
    doc["detector"] = {**DetectorModel.illustrative().to_dict(),
                       "fit": {"classes": ["person", "car"]}}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    d = Driver(tmp_path / "m.yaml", tmp_path / "rec")
    d.link(b"".join(pack(m, seq=i) for i, m in enumerate(Hover(seconds=30.0).messages())))
    person = Box("person", 0.9, 310.0, 200.0, 18.0, 40.0)
    d.frames(encode_frames_v2([
        FrameBoxes(29.0, (person, Box("invented7", 0.9, 100.0, 100.0, 9.0, 9.0))),
        FrameBoxes(1e6, (person,)), FrameBoxes(5.0, (person,))]))
    faults = d.core.status(d.now_s, LinkReport())[0]["faults"]
    assert faults["boxes_refused_unknown_class"] == 1, faults
    assert faults["frames_refused_ahead_of_clock"] == 1, faults
    assert faults["frames_refused_too_old"] == 1, faults  # 5 s: 24 s behind, history 20 s
    assert faults["boxes_of_frames_not_taken"] == 2, faults


def test_time_utc_live_is_evaluate_s_from_system_time(tmp_path: Path) -> None:
    """SYSTEM_TIME gives every detection and candidate its UTC, live and offline alike: a
    frame at t_boot_s 2.0 of a boot whose time_boot_ms 0 was 2026-12-06T21:40:00.000Z is
    at 21:40:02.000Z."""
    from datetime import datetime, timedelta, timezone

    cfg_path = _config(tmp_path)
    d = Driver(cfg_path, tmp_path / "rec")
    boot = datetime(2026, 12, 6, 21, 40, tzinfo=timezone.utc)
    hover = Hover(seconds=4.0, boot_unix_us=round(boot.timestamp() * 1e6))
    d.link(b"".join(pack(m, seq=i) for i, m in enumerate(hover.messages())))
    rng = np.random.default_rng(3)
    frames = [FrameBoxes(1.2 + 0.2 * k, _boxes(k, rng)) for k in range(12)]
    d.frames(encode_frames_v2(frames))
    d.core.process()
    for _ in range(5):
        d.tick(DETECTIONS_PERIOD_S)
    d.recorder.close()
    live = [x for msg in d.published for x in msg["detections"]]
    assert live
    for x in live:
        assert datetime.fromisoformat(x["time_utc"]) == boot + timedelta(
            milliseconds=round(x["t_boot_s"] * 1000)), x
    live_candidates = decode_detections(d.core.candidates_payload())["candidates"]
    for c in live_candidates:
        assert c["first_time_utc"] <= c["last_time_utc"]
        assert datetime.fromisoformat(c["last_time_utc"]) == boot + timedelta(
            milliseconds=round(c["last_t_boot_s"] * 1000)), c
    offline, out = _offline_is_live(tmp_path, cfg_path, live, live_candidates)
    features = json.loads((out / "detections.geojson").read_text())["features"]
    assert {f["properties"]["time_utc"] for f in features
            if f["properties"]["kind"] == "detection"} == {x["time_utc"] for x in live}
    import gpxpy

    with open(out / "pdcov.gpx", encoding="utf-8") as f:
        gpx = gpxpy.parse(f)
    points = [p for s in gpx.tracks[0].segments for p in s.points]
    # The hover's positions, 10 a second from time_boot_ms 1000: 21:40:01.000Z on.
    assert [p.time for p in points[:2]] == [boot + timedelta(seconds=1.0),
                                            boot + timedelta(seconds=1.1)]
    by_uid = {c["uid"]: c for c in offline["candidates"]}
    for w in gpx.waypoints:
        assert w.time == datetime.fromisoformat(by_uid[w.name]["last_time_utc"])
