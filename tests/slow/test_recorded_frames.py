"""Frames from the onboard detector (``service.frame_source: zenoh``) are written into the
daemon's recording, so that ``pdcov evaluate`` of the recording gives the live grid cell for
cell (telemetry.recorded_frames). In memory: the daemon's own message, frames and processing
steps on a running event loop, a real recorder, MAVLink bytes through pymavlink; the frames
payloads held before the autopilot is known, out of order, duplicated, late, damaged, with
sub-millisecond times, across an autopilot reboot, and a camera's own capture events in the
same log. The end-to-end flight with a real Zenoh publisher is
tests/simulators/test_serve_fly.py."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import numpy as np
import yaml

from pdcov.bus.frames import encode_frames
from pdcov.cli import main as pdcov_main
from pdcov.config.load import load_mission
from pdcov.service.daemon import Daemon
from pdcov.service.recorder import TlogRecorder
from pdcov.service.settings import load_serve_config
from pdcov.telemetry.logs import read_flight_log
from pdcov.telemetry.recorded_frames import (
    MARK,
    SOURCE,
    FrameEncoder,
    frame_source_for,
    recorded_mark,
)
from pdcov.telemetry.tlog import mavlink
from tests.support.link_feed import FIXED, MISSION, Hover, pack

CAMERA = 100  # MAV_COMP_ID_CAMERA


def _parse(data: bytes) -> list:
    p = mavlink.MAVLink(None)
    return p.parse_buffer(data) or []


def _segment(boot_shift_ms: int = 0) -> list[bytes]:
    """A 4 s hover (autopilot time 1.0..4.9 s, + boot_shift_ms) and a camera (component
    100, a clock of its own) capturing every 0.5 s."""
    out = []
    for i, msg in enumerate(Hover(seconds=4.0).messages()):
        if hasattr(msg, "time_boot_ms"):
            msg.time_boot_ms += boot_shift_ms
        out.append(pack(msg, seq=i))
        if msg.get_type() == "ATTITUDE" and msg.time_boot_ms % 500 == 0:
            cam = mavlink.MAVLink(None).camera_image_captured_encode(
                msg.time_boot_ms + 77_000, 0, 0, 0, 0, 0, 0, [1, 0, 0, 0], i, 1, b"")
            out.append(pack(cam, component_id=CAMERA, seq=i))
    return out


def _config(tmp: Path, frame_source: str | None = "zenoh", name: str = "m.yaml",
            log: dict | None = None):
    """The mission config (no log section unless ``log`` is given) at ``tmp/name``."""
    doc = dict(MISSION, mount=FIXED)
    doc["service"] = {"state_dir": str(tmp / "state"), "frame_source": frame_source,
                      "reorder_s": 0.0}
    if log:
        doc["log"] = log
    (tmp / name).write_text(yaml.safe_dump(doc))
    return tmp / name


class Link(bytes):
    """MAVLink bytes from the link (other steps are frames payloads)."""


def evaluate(cfg_path: Path, rec: Path, out: Path, *options: str) -> dict:
    """``pdcov evaluate`` (its CLI main) of the recording: the grid arrays and frames."""
    assert pdcov_main(["evaluate", "--config", str(cfg_path), "--log", str(rec), "--out",
                       str(out), "--no-progress", *options]) == 0
    with np.load(out / "grid.npz") as z:
        return {k: z[k] for k in ("frames", "log_miss_d", "log_miss_fa", "n_obs")}


def evaluated_is_live(cfg_path: Path, rec: Path, out: Path, live, *options: str) -> None:
    """``pdcov evaluate`` of the recording (with ``options``): the live grid, array for
    array."""
    grid = evaluate(cfg_path, rec, out, *options)
    assert int(grid["frames"]) == live.grid.frames
    for key in ("log_miss_d", "log_miss_fa", "n_obs"):
        assert np.array_equal(grid[key], getattr(live.grid, key)), key


async def _fly(d: Daemon, steps: list[bytes]) -> None:
    """Each step: Link bytes to the daemon's message handler, else a frames payload to its
    Zenoh handler (as the loop gets it); the loop runs between steps."""
    for step in steps:
        if isinstance(step, Link):
            d._on_messages(None, _parse(step))
        else:
            d.bus.on_frames(step)
        await asyncio.sleep(0)
    d.live.process()


def test_evaluate_of_the_recording_is_the_live_grid(tmp_path: Path, capsys) -> None:
    cfg_path = _config(tmp_path)
    d = Daemon(load_serve_config(cfg_path))
    d.effects.recorder = TlogRecorder(tmp_path / "rec", 1 << 20, 1 << 30)
    first, second = _segment(), _segment(boot_shift_ms=-500)  # the autopilot rebooted
    half = len(first) // 2
    frames = encode_frames
    steps: list[bytes] = [
        frames([1.05, 1.15]),                        # before any HEARTBEAT: held
        Link(b"".join(first[:half])),
        frames([1.45, 1.25, 1.35, 1.25]),            # out of order, a duplicate inside
        frames([1.25]),                              # a duplicate of a queued frame
        b"not json",                                 # refused, counted
        frames([1.5504, 1.9996]),                    # to the millisecond: 1.550, 2.000
        Link(b"".join(first[half:])),
        frames([1.3]),                               # late: a later frame was decided
        frames([4.5, 3.0, 2.2]),
        Link(b"".join(second)),
        frames([0.95, 2.6, 2.61]),                   # the new boot's clock
    ]
    asyncio.run(_fly(d, steps))
    d.effects.recorder.close()
    live = d.live
    c = live.counters
    assert c.skipped["late frame time"] == 1, c.skipped
    assert c.faults["bad_frames_messages"] == 1, c.faults
    assert live.frames_pending == 0
    assert live.grid.frames == c.used > 6, (c.used, c.skipped)

    rec = next((tmp_path / "rec").glob("flight-*.tlog"))
    log = read_flight_log(rec)
    assert {x.source for x in log.captures} == {SOURCE}   # never the camera's captures
    assert len(log.captures) == 13  # 2 held + 3 + 2 + 3 + 3; no duplicate, not the late one
    # The boot clock: the second boot is placed after the first (and offline, last boot
    # keeps its own time), so the reboot's frames come last, at their own times.
    # The clock: offline, the last boot keeps its own time and the first is placed before
    # it (its last sample 4.9 s + REBOOT_GAP_S 60 s); the frames with their boot's.
    t = np.sort([x.t_s for x in log.captures])
    np.testing.assert_allclose(t[:10] + 64.9, [1.05, 1.15, 1.25, 1.35, 1.45, 1.55, 2.0, 2.2,
                                               3.0, 4.5], atol=1e-9)
    np.testing.assert_allclose(t[10:], [0.95, 2.6, 2.61], atol=1e-9)
    assert any("frame times pdcov serve took from its detector" in n
               and "not the camera's" in n for n in log.notes), log.notes

    evaluated_is_live(cfg_path, rec, tmp_path / "offline", live, "--frame-source", "capture")
    summary = capsys.readouterr().out
    assert f"13 capture events ({SOURCE})" in summary, summary
    assert "not the camera's 16 capture events" in summary, summary


def test_a_recorded_frame_is_not_a_camera_capture() -> None:
    data = FrameEncoder().encode(7, 123_456)
    (msg,) = _parse(data)
    assert recorded_mark(msg) == MARK
    assert (msg.get_srcSystem(), msg.get_srcComponent(), msg.time_boot_ms) == (7, 191, 123_456)

    def camera(url: bytes, component: int):
        msg = mavlink.MAVLink(None).camera_image_captured_encode(
            123_456, 0, 0, 0, 0, 0, 0, [1, 0, 0, 0], 0, 1, url)
        return _parse(pack(msg, 7, component))[0]

    # The mark from another component, or component 191 without the mark: a camera's.
    assert recorded_mark(camera(b"pdcov:detector-frame", CAMERA)) is None
    assert recorded_mark(camera(b"file:///img/0001.jpg", 191)) is None
    assert recorded_mark(camera(b"pdcov:detector-frame", 191)) == MARK


def test_capture_frames_duplicated_or_late_evaluate_to_the_live_grid(tmp_path: Path) -> None:
    """``frame_source: capture``: the autopilot's CAMERA_IMAGE_CAPTURED every 0.3 s, one
    sent twice at once, the same again late, and one held back until later frames were
    decided (late: the daemon does not take it). ``pdcov evaluate`` of the recording gives
    the live grid."""
    cfg_path = _config(tmp_path, "capture")
    d = Daemon(load_serve_config(cfg_path))
    d.effects.recorder = TlogRecorder(tmp_path / "rec", 1 << 20, 1 << 30)
    mav = mavlink.MAVLink(None)

    def capture(ms: int) -> bytes:
        return pack(mav.camera_image_captured_encode(ms, 0, 0, 0, 0, 0, 0, [1, 0, 0, 0],
                                                     ms // 100, 1, b""))

    steps: list[bytes] = []
    for i, msg in enumerate(Hover(seconds=4.0).messages()):
        steps.append(Link(pack(msg, seq=i)))
        ms = msg.time_boot_ms if msg.get_type() == "ATTITUDE" else 0
        if ms == 3300:  # late (less than 2 s: more would be an autopilot reboot)
            steps += [Link(capture(2100)), Link(capture(1500))]
        if not ms or ms % 300 or ms == 2100:
            continue
        steps.append(Link(capture(ms)))
        if ms == 1500:
            steps.append(Link(capture(1500)))                 # a duplicate at once
    asyncio.run(_fly(d, steps))
    d.effects.recorder.close()
    live = d.live
    assert live.counters.skipped["late frame time"] == 2, live.counters.skipped
    assert live.frames_pending == 0
    assert live.grid.frames == live.counters.used == 12, live.counters.skipped

    rec = next((tmp_path / "rec").glob("flight-*.tlog"))
    log = read_flight_log(rec)  # 15 capture events, the 2 late ones marked as not taken
    assert sorted(round(c.t_s * 1000) for c in log.captures) == [
        1200, 1500, 1500, 1800, *range(2400, 4801, 300)], log.captures
    assert any(n.startswith("2 capture events pdcov serve did not take") for n in log.notes)
    evaluated_is_live(cfg_path, rec, tmp_path / "offline", live, "--frame-source", "capture")


def test_evaluate_uses_the_recorded_frames_unless_rate_is_chosen(tmp_path: Path,
                                                                 capsys) -> None:
    """A recording of ``service.frame_source: zenoh``, the config setting no
    log.frame_source: ``pdcov evaluate`` with no frame source option gives the daemon's
    grid, cell for cell, and says why; a frame source 'rate' chosen on the command line or
    in the config is honoured (a rate lattice, not the daemon's grid) with a warning."""
    cfg_path = _config(tmp_path)
    d = Daemon(load_serve_config(cfg_path))
    d.effects.recorder = TlogRecorder(tmp_path / "rec", 1 << 20, 1 << 30)
    link = _segment()
    half = len(link) // 2
    asyncio.run(_fly(d, [Link(b"".join(link[:half])), encode_frames([1.5, 2.0]),
                         Link(b"".join(link[half:])), encode_frames([2.5, 3.25, 4.0])]))
    d.effects.recorder.close()
    live = d.live
    assert live.grid.frames == live.counters.used == 5, live.counters.skipped
    rec = next((tmp_path / "rec").glob("flight-*.tlog"))
    capsys.readouterr()

    evaluated_is_live(cfg_path, rec, tmp_path / "default", live)
    out, err = capsys.readouterr()
    assert "frame source: the 5 detector frames pdcov serve recorded" in out, out
    assert f"frames: 5 capture events ({SOURCE}); 5 used of 5" in out, out
    assert "WARNING" not in out + err, (out, err)
    assert "warnings" not in json.loads((tmp_path / "default" / "metrics.json").read_text())

    rate = evaluate(cfg_path, rec, tmp_path / "rate", "--frame-source", "rate")
    out, err = capsys.readouterr()
    assert f"frames: every {1 / MISSION['camera']['frame_rate_hz']:g} s" in out, out
    assert int(rate["frames"]) != live.grid.frames
    assert not np.array_equal(rate["n_obs"], live.grid.n_obs)
    assert "pdcov evaluate: WARNING: frame source 'rate' was chosen" in err, err
    assert "not the 5 detector frames pdcov serve recorded" in err, err
    assert "WARNING: frame source 'rate' was chosen" in out, out  # beside the frames line
    doc = json.loads((tmp_path / "rate" / "metrics.json").read_text())
    assert any("frame source 'rate' was chosen" in w for w in doc["warnings"]), doc

    # log.frame_source: rate in the config is a choice too; capture is the daemon's grid.
    rate_cfg = _config(tmp_path, name="rate.yaml", log={"frame_source": "rate"})
    again = evaluate(rate_cfg, rec, tmp_path / "rate-cfg")
    assert "frame source 'rate' was chosen" in capsys.readouterr().err
    for key, value in rate.items():
        assert np.array_equal(again[key], value), key
    capture_cfg = _config(tmp_path, name="capture.yaml", log={"frame_source": "capture"})
    evaluated_is_live(capture_cfg, rec, tmp_path / "capture-cfg", live)


def test_frame_source_for() -> None:
    assert frame_source_for(None, 0).source == "rate"
    assert frame_source_for(None, 0).line == frame_source_for(None, 0).warning == ""
    chosen = frame_source_for(None, 7)
    assert chosen.source == "capture" and "the 7 detector frames" in chosen.line
    assert not chosen.warning
    assert frame_source_for("rate", 7).source == "rate"
    assert "not the 7 detector frames" in frame_source_for("rate", 7).warning
    assert frame_source_for("rate", 0) == frame_source_for("rate", 0).__class__("rate")
    assert frame_source_for("capture", 7).source == "capture"
    assert not frame_source_for("capture", 7).warning


def test_the_config_says_whether_a_frame_source_was_chosen(tmp_path: Path) -> None:
    """Mission.frame_source stays 'rate' when log.frame_source is not set (the daemon and
    the simulator read it so); chosen_frame_source tells a default from a choice."""
    unset = load_mission(_config(tmp_path))
    assert (unset.frame_source, unset.frame_source_set, unset.chosen_frame_source) == (
        "rate", False, None)
    for value in ("rate", "capture"):
        m = load_mission(_config(tmp_path, name=f"{value}.yaml", log={"frame_source": value}))
        assert (m.frame_source, m.chosen_frame_source) == (value, value)
    # Without log.frame_source, evaluate follows the daemon's service.frame_source in the
    # same file: 'capture' and 'rate' as the daemon flew; 'zenoh' by the recorded frames.
    for daemon, chosen in (("capture", "capture"), ("rate", "rate"), ("zenoh", None),
                           (None, None)):
        m = load_mission(_config(tmp_path, daemon, name=f"d-{daemon}.yaml"))
        assert (m.frame_source, m.chosen_frame_source) == ("rate", chosen), daemon
    m = load_mission(_config(tmp_path, "capture", name="both.yaml", log={"frame_source": "rate"}))
    assert m.chosen_frame_source == "rate"  # log.frame_source wins
    # The daemon's default: service.frame_source null and log.frame_source not set.
    assert load_serve_config(_config(tmp_path, None, name="s.yaml")).frame_source == "rate"
