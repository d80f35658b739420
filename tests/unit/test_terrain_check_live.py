"""The DEM cross-check live (ServiceCore fed a link in memory, tests/support/link_feed.py) and
offline (the same bytes as a tlog through ``poses_from_log``, as ``pdcov evaluate`` does): the same
counts; the daemon's warning rate; the status field and its decoder."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.status import StatusEncoder, decode_status, encode_status, merge_status
from pdcov.flight.frame_decision import Framing
from pdcov.flight.log_frames import poses_from_log
from pdcov.service.coverage import TERRAIN_WARNING_PERIOD_S
from pdcov.telemetry.samples import TerrainReportSample
from pdcov.telemetry.terrain_check import TerrainCheck
from tests.support.link_feed import GROUND_M, Hover, LinkFeed, pack, serve_config


class FlatDem:
    """Ground at ``alt_msl_m`` everywhere."""

    def __init__(self, alt_msl_m: float) -> None:
        self.alt_msl_m = alt_msl_m

    def height_msl_m(self, lat_deg, lon_deg):
        import numpy as np
        return np.full(np.shape(lat_deg), self.alt_msl_m)


def terrain_messages() -> list[bytes]:
    """The hovering vehicle (12 m above the 488 m home) with a downward rangefinder between
    its positions and a terrain report every second; the readings: 12 m (the ground at
    488 m), every 4th 2 m (the ground at 498 m), every 5th forward-facing, every 7th beyond
    its maximum; a companion computer's rangefinder too. The terrain reports alternate
    between 488 m and 499 m."""
    mav = mavlink.MAVLink(None)
    out: list[bytes] = []
    k = 0
    for msg in Hover().messages():
        out.append(pack(msg, seq=len(out)))
        if msg.get_type() != "GLOBAL_POSITION_INT":
            continue
        ms = msg.time_boot_ms + 50
        d_cm = 200 if k % 4 == 0 else 1200
        orientation = 0 if k % 5 == 0 else 25
        hi_cm = 1000 if k % 7 == 0 else 4000
        out.append(pack(mav.distance_sensor_encode(ms, 20, hi_cm, d_cm, 0, 0, orientation, 0),
                        seq=len(out)))
        out.append(pack(mav.distance_sensor_encode(ms, 20, 4000, 3000, 0, 0, 25, 0),
                        component_id=197, seq=len(out)))  # not the autopilot's: ignored
        if k % 10 == 5:
            terrain = GROUND_M + (0.0 if k % 20 == 5 else 11.0)
            out.append(pack(mav.terrain_report_encode(msg.lat, msg.lon, 30, terrain, 12.0, 0,
                                                      16), seq=len(out)))
        k += 1
    return out


def test_live_and_offline_counts_are_the_same(tmp_path: Path) -> None:
    data = terrain_messages()
    tlog = tmp_path / "terrain.tlog"
    tlog.write_bytes(b"".join(struct.pack(">Q", 1_700_000_000_000_000 + 1000 * i) + d
                              for i, d in enumerate(data)))
    cfg = serve_config(tmp_path)
    dem = FlatDem(GROUND_M + 12.0)  # 12 m too high

    feed = LinkFeed(cfg)
    feed.live.terrain_check = TerrainCheck(dem)
    for i, chunk in enumerate(data):
        feed.feed(chunk, 0.001 * i)
    feed.tick(10.0)
    live = feed.live.terrain_check.as_dict()

    offline = TerrainCheck(dem)
    m = cfg.mission
    (cam,) = m.cameras
    poses_from_log(tlog, Framing(cam.mount, cam.frame_rate_hz, max_gap_s=m.max_gap_s),
                   origin_lat_deg=m.origin_lat_deg, origin_lon_deg=m.origin_lon_deg,
                   ground_alt_msl_m=m.ground_alt_msl_m, terrain_check=offline)
    assert offline.as_dict() == live
    # 40 readings (k = 0..39): 8 forward-facing (k % 5 == 0), 3 of 12 m beyond their 10 m
    # maximum (k = 7, 14, 21), the last waits for a position after it; 28 compared: 20 of
    # 12 m (12 m off), 8 of 2 m (k % 4 == 0: 2 m off). 4 terrain reports, 2 of 488 m (12 m
    # off), 2 of 499 m (1 m off). One home (488 m: 12 m off; sent before the autopilot's
    # first time, which a home needs not).
    assert live["refused"] == {"rangefinder not downward": 8, "rangefinder out of range": 3}
    assert live["checked"] == {"terrain_report": 4, "rangefinder": 28, "home": 1}
    assert live["mismatches"] == 2 + 20 + 1
    assert live["largest"]["difference_m"] == pytest.approx(12.0, abs=0.01)
    status = feed.status()
    assert status["faults"]["terrain_mismatch"] == 23
    assert decode_status(encode_status(status))["terrain_check"] == json.loads(
        json.dumps(live))


def test_warning_is_logged_first_then_at_most_once_a_minute(tmp_path: Path) -> None:
    feed = LinkFeed(serve_config(tmp_path))
    live = feed.live
    live.terrain_check = TerrainCheck(FlatDem(GROUND_M + 12.0))

    def warnings_at(now_s: float, n_reports: int) -> list[str]:
        for _ in range(n_reports):
            live.add_sample(TerrainReportSample(now_s, 47.39, 8.54, GROUND_M, 12.0, True))
        return [n for n in live.poll(now_s).notes if n.startswith("terrain check")]

    assert warnings_at(0.0, 0) == []
    first = warnings_at(1.0, 1)
    assert len(first) == 1 and "+12.0 m (terrain_report at" in first[0]
    assert "1 disagreements so far" in first[0] and "vertical datum" in first[0]
    assert warnings_at(2.0, 5) == []  # counted, not said
    assert warnings_at(1.0 + TERRAIN_WARNING_PERIOD_S, 0) != []  # the 5 since, said once
    assert warnings_at(2.0 + TERRAIN_WARNING_PERIOD_S, 0) == []  # nothing new
    assert live.terrain_check.mismatches == 6


def test_status_decoder_accepts_the_field_and_refuses_a_malformed_one(tmp_path: Path) -> None:
    feed = LinkFeed(serve_config(tmp_path))
    plain = feed.status()
    assert "terrain_check" not in plain  # no DEM: the status is as before
    decode_status(encode_status(plain))
    feed.live.terrain_check = check = TerrainCheck(FlatDem(GROUND_M + 12.0))
    check.add(TerrainReportSample(1.0, 47.39, 8.54, GROUND_M, 12.0, True))
    fields = feed.status()
    doc = decode_status(encode_status(fields))
    assert doc["terrain_check"]["largest"]["difference_m"] == 12.0
    assert doc["faults"]["terrain_mismatch"] == 1
    for bad, field in (({"mismatches": -1}, "terrain_check.mismatches"),
                       ({"margin_m": "10"}, "terrain_check.margin_m"),
                       ({"refused": {"x": 1.5}}, "terrain_check.refused.x"),
                       ({"largest": {**doc["terrain_check"]["largest"], "lat_deg": 91}},
                        "terrain_check.largest.lat_deg"),
                       ({"latest": {"source": "home"}}, "terrain_check.latest.difference_m")):
        broken = {**fields, "terrain_check": {**fields["terrain_check"], **bad}}
        with pytest.raises(BusPayloadError, match=field.replace(".", r"\.")):
            decode_status(encode_status(broken))
    with pytest.raises(BusPayloadError, match="terrain_check: expected an object"):
        decode_status(encode_status({**fields, "terrain_check": [1]}))


def test_brief_status_leaves_it_out_and_the_merge_keeps_it(tmp_path: Path) -> None:
    feed = LinkFeed(serve_config(tmp_path))
    feed.live.terrain_check = check = TerrainCheck(FlatDem(GROUND_M + 12.0))
    enc = StatusEncoder()
    full = decode_status(enc.encode(feed.status()))
    check.add(TerrainReportSample(1.0, 47.39, 8.54, GROUND_M, 12.0, True))
    brief = decode_status(enc.encode(feed.status()))  # a new mismatch: no detail change
    assert full["full"] is True and brief["full"] is False
    assert "terrain_check" not in brief and brief["faults"]["terrain_mismatch"] == 1
    assert merge_status(full, brief)["terrain_check"] == full["terrain_check"]


def test_a_home_beyond_max_home_offset_refuses_the_dem_live_and_offline(tmp_path: Path
                                                                        ) -> None:
    """The DEM 188 m above the home (a wrong datum), terrain.max_home_offset_m 30: the daemon
    counts no frame over it (each skipped as 'home off the DEM'), says why once in its log
    and to the pilot; offline, the same samples refuse the DEM with the same words."""
    data = terrain_messages()
    cfg = serve_config(tmp_path)
    dem = FlatDem(GROUND_M + 188.0)
    feed = LinkFeed(cfg)
    live = feed.live
    live.terrain_check = TerrainCheck(dem, max_home_offset_m=30.0)
    done = []  # what the core tells its shell to do
    actions = feed.core.actions
    feed.core.actions = lambda: done.append(actions()) or done[-1]  # type: ignore[method-assign]
    for i, chunk in enumerate(data):
        feed.feed(chunk, 0.001 * i)
    feed.tick(10.0)
    notes = [text for a in done for _level, text in a.logs]
    texts = [m.text for a in done for m in a.send if m.get_type() == "STATUSTEXT"]
    status = feed.status()
    assert live.grid.frames == 0
    skipped = status["frames"]["skipped"]
    assert skipped.get("home off the DEM", 0) > 0, skipped
    assert status["faults"]["home_off_dem"] == 1
    refusal = live.terrain_check.home_refusal()
    assert refusal is not None and "-188.0 m from the DEM" in refusal
    assert "terrain.max_home_offset_m = 30 m" in refusal
    assert notes.count(refusal) == 1
    assert texts[:1] == ["pdcov: home -188m off DEM, no coverage"] and len(texts[0]) <= 50

    # The same DEM 12 m off (the margin's mismatch, not a refusal): frames are counted.
    feed = LinkFeed(serve_config(tmp_path))
    feed.live.terrain_check = TerrainCheck(FlatDem(GROUND_M + 12.0), max_home_offset_m=30.0)
    for i, chunk in enumerate(data):
        feed.feed(chunk, 0.001 * i)
    feed.tick(10.0)
    assert feed.live.grid.frames > 0 and feed.live.terrain_check.home_refusal() is None

    tlog = tmp_path / "terrain.tlog"
    tlog.write_bytes(b"".join(struct.pack(">Q", 1_700_000_000_000_000 + 1000 * i) + d
                              for i, d in enumerate(data)))
    offline = TerrainCheck(dem, max_home_offset_m=30.0)
    m = cfg.mission
    (cam,) = m.cameras
    poses_from_log(tlog, Framing(cam.mount, cam.frame_rate_hz, max_gap_s=m.max_gap_s),
                   origin_lat_deg=m.origin_lat_deg, origin_lon_deg=m.origin_lon_deg,
                   ground_alt_msl_m=m.ground_alt_msl_m, terrain_check=offline)
    assert offline.home_refusal() == refusal
