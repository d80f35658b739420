"""pdcov.gpx (report/gpx.py) read back by gpxpy's parser: a track per vehicle with a
segment per flight at the positions given (7 decimals, elevations MSL), UTC times only
where known, a waypoint per candidate named by its uid; long tracks thinned keeping their
ends; and the tracks ``pdcov evaluate`` (its pose CSV's camera positions) and the
watcher's recording (its status positions) give it. GDAL's reader is in
tests/integration/test_exports_readers.py."""

from __future__ import annotations

import csv
import re
from datetime import datetime, timezone
from importlib import resources
from pathlib import Path

import gpxpy
import numpy as np
import pytest

from pdcov.bus.status import decode_status
from pdcov.cli import main
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.ground.record_exports import ExportRecorder
from pdcov.ground.watcher import Watcher
from pdcov.report.exports import TrackSegment, VehicleDetections, VehicleTrack, write_exports
from pdcov.report.gpx import thinned
from tests.support.exports_fixtures import ORIGIN, coverage, detections_doc
from tests.support.watch_fixtures import PINNED_SESSION, pinned

POSES = Path(__file__).resolve().parents[1] / "data" / "poses_nadir_10m.csv"
MISSION = str(resources.files("pdcov") / "data" / "demo_mission.yaml")
T0 = 1_767_225_600.25  # 2026-01-01T00:00:00.25Z


def flights() -> list[np.ndarray]:
    """Two flights, ENU m about ORIGIN: a leg east at 30 m, a leg north at 40 m."""
    x = np.linspace(-20.0, 20.0, 41)
    return [np.c_[x, np.zeros_like(x), np.full_like(x, 30.0)],
            np.c_[np.zeros(11), np.linspace(-10.0, 10.0, 11), np.full(11, 40.0)]]


def read(path: Path) -> gpxpy.gpx.GPX:
    with open(path, encoding="utf-8") as f:
        return gpxpy.parse(f)


def test_tracks_and_waypoints_read_back_with_gpxpy(tmp_path):
    first, second = flights()
    timed = VehicleTrack("alpha", (
        TrackSegment(enu_to_geodetic(first, ORIGIN), T0 + np.arange(len(first))),
        VehicleTrack.from_enu("alpha", [second], ORIGIN).segments[0]))
    write_exports(tmp_path, coverage(), [VehicleDetections.from_doc(detections_doc())],
                  title="gpx", tracks=[timed, VehicleTrack("bravo", ())])
    text = (tmp_path / "pdcov.gpx").read_text()
    doc = gpxpy.parse(text)
    assert doc.version == "1.1" and doc.creator == "pdcov" and doc.name == "gpx"
    (trk,) = doc.tracks  # bravo flew nowhere: no track
    assert trk.name == "alpha" and len(trk.segments) == 2
    for seg, enu in zip(trk.segments, (first, second), strict=True):
        back = np.array([[p.latitude, p.longitude, p.elevation] for p in seg.points])
        assert back[:, :2] == pytest.approx(enu_to_geodetic(enu, ORIGIN)[:, :2], abs=0.5e-7)
        assert back[:, 2] == pytest.approx(ORIGIN.ground_alt_msl_m + enu[:, 2], abs=0.005)
    assert [p.time for p in trk.segments[0].points[:2]] == [
        datetime(2026, 1, 1, 0, 0, 0, 250000, timezone.utc),
        datetime(2026, 1, 1, 0, 0, 1, 250000, timezone.utc)]
    assert "<time>2026-01-01T00:00:00.250000Z</time>" in text  # UTC, ISO 8601
    assert all(p.time is None for p in trk.segments[1].points)  # no real time known
    decimals = re.findall(r'(?:lat|lon)="-?\d+\.(\d+)"', text)
    assert decimals and max(map(len, decimals)) <= 7
    src = detections_doc()["candidates"]
    assert [(w.name, w.latitude, w.longitude, w.elevation, w.type) for w in doc.waypoints] \
        == [(c["uid"], pytest.approx(c["lat_deg"], abs=0.5e-7),
             pytest.approx(c["lon_deg"], abs=0.5e-7), pytest.approx(c["alt_msl_m"]),
             "person") for c in src]
    assert doc.waypoints[0].description == (
        "pin 1: person alpha.3fa2c1.3: p_person 0.97, detected 9 of 14 looks; sigma 0.5 m; "
        "MGRS 32T LS 65735 51092")


def test_unknown_altitudes_are_left_out(tmp_path):
    det = detections_doc()
    del det["candidates"][0]["alt_msl_m"]
    write_exports(tmp_path, None, [VehicleDetections.from_doc(det)], title="t",
                  tracks=[VehicleTrack.from_enu("alpha", flights()[:1], Origin(46.5, 7.25),
                                                heights_msl=False)])
    doc = read(tmp_path / "pdcov.gpx")
    assert [w.elevation for w in doc.waypoints] == [None, pytest.approx(600.0)]
    assert all(p.elevation is None for p in doc.tracks[0].segments[0].points)


def test_a_long_track_keeps_every_nth_point_and_each_flights_ends():
    n = 25_001
    a = np.c_[np.linspace(46.0, 46.1, n), np.full(n, 7.0), np.full(n, 500.0)]
    a[7] = np.nan  # not a position: dropped
    segs = thinned([TrackSegment(a, np.arange(n, dtype=float)), TrackSegment(a[:3])],
                   max_points=10_000)
    # 25,003 positions: every 3rd (25,000 finite, the last among them), the second
    # flight's first and last
    assert [len(s.lat_lon_alt) for s in segs] == [8334, 2]
    assert segs[0].lat_lon_alt[0, 0] == 46.0 and segs[0].lat_lon_alt[-1, 0] == 46.1
    assert segs[0].t_unix_s is not None and segs[0].t_unix_s[1] == 3.0
    assert np.isfinite(segs[0].lat_lon_alt).all()


def test_evaluate_exports_the_flown_track(tmp_path):
    assert main(["evaluate", "--config", MISSION, "--poses", str(POSES), "--out",
                 str(tmp_path / "run"), "--no-progress"]) == 0
    with open(POSES, newline="") as f:
        enu = np.array([[float(r["x_m"]), float(r["y_m"]), float(r["z_m"])]
                        for r in csv.DictReader(f)])
    (trk,) = read(tmp_path / "run" / "pdcov.gpx").tracks
    (seg,) = trk.segments  # one input, one flight
    assert trk.name == "demo" and len(seg.points) == len(enu)
    lla = enu_to_geodetic(enu, Origin(39.35, -76.33, 5.0))  # the mission's origin
    back = np.array([[p.latitude, p.longitude, p.elevation] for p in seg.points])
    assert back[:, :2] == pytest.approx(lla[:, :2], abs=0.5e-7)
    assert back[:, 2] == pytest.approx(lla[:, 2], abs=0.005)
    assert all(p.time is None for p in seg.points)  # a pose CSV's clock is no real time


def test_the_watchers_recording_exports_each_vehicles_track(tmp_path):
    rec = ExportRecorder(tmp_path / "exports", period_s=1.0)
    w, pub = pinned(Watcher(detection_log=rec.detection_log))
    for _ in range(3):
        pub.step(2)
        w.on_status("uav1", decode_status(pub.status()), 1.0, PINNED_SESSION)
    assert rec.write(w) and "pdcov.gpx" in rec.last.files
    held = np.array(w.feeds["uav1"].track_lat_lon_alt)
    assert len(held) == 4
    (trk,) = read(tmp_path / "exports" / "pdcov.gpx").tracks
    back = np.array([[p.latitude, p.longitude, p.elevation] for p in trk.segments[0].points])
    assert trk.name == "uav1" and back == pytest.approx(held, abs=0.5e-7)


def test_waypoints_take_their_candidates_time_utc_and_cot_markers_too(tmp_path):
    """A candidate last detected at 2026-12-06T21:42:01.250Z (its ``last_time_utc``): its
    GPX waypoint's time, and its CoT event's time and start (gpxpy and ElementTree read
    them back); a candidate without one has neither."""
    import xml.etree.ElementTree as ET

    from pdcov.report.cot_events import candidate_event

    doc = detections_doc()
    doc["candidates"][0]["last_time_utc"] = "2026-12-06T21:42:01.250Z"
    doc["candidates"][0]["first_time_utc"] = "2026-12-06T21:41:58.000Z"
    doc["candidates"][1]["last_time_utc"] = None
    write_exports(tmp_path, None, [VehicleDetections.from_doc(doc)], title="t")
    when = datetime(2026, 12, 6, 21, 42, 1, 250_000, timezone.utc)
    assert [w.time for w in read(tmp_path / "pdcov.gpx").waypoints] == [when, None]
    now_s = datetime(2026, 12, 6, 22, 0, tzinfo=timezone.utc).timestamp()
    seen = ET.fromstring(candidate_event("alpha", doc["candidates"][0], now_s, 300.0))
    assert (seen.get("time"), seen.get("start"), seen.get("stale")) == (
        "2026-12-06T21:42:01.250Z", "2026-12-06T21:42:01.250Z", "2026-12-06T22:05:00.000Z")
    unseen = ET.fromstring(candidate_event("alpha", doc["candidates"][1], now_s, 300.0))
    assert unseen.get("time") == unseen.get("start") == "2026-12-06T22:00:00.000Z"
