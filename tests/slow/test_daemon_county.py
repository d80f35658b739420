"""The daemon's decisions over a county (30 x 30 km at 1 m, 9 x 10^8 cells): frames, tiles
and status follow the cells the flight touched, never the domain, in memory as over a small
square, and its flown cells equal the small square's grid."""

from __future__ import annotations

import json
import tracemalloc

import numpy as np
import pytest
import shapely

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.status import decode_status, encode_status
from pdcov.bus.tiled_snapshot import decode_grid_snapshot, encode_grid_snapshot
from pdcov.bus.tiles import decode_tiles
from pdcov.core.grid_layer import Layer
from pdcov.core.grid_store import read_store_like
from pdcov.ground.record import Recording
from pdcov.ground.record_exports import coverage_of
from pdcov.ground.watcher import Watcher
from tests.support.service_feed import (
    COUNTY,
    SIDE_M,
    SQUARE_ENU_M,
    X0_M,
    Y0_M,
    feed,
    flown,
)

LAYERS = (Layer.N_OBS, Layer.LOG_MISS_D, Layer.LOG_MISS_FA, Layer.LIMITING)


def test_a_county_flight_costs_what_a_small_one_does():
    small, small_tiles, small_status = flown(SQUARE_ENU_M)
    tracemalloc.start()
    try:
        county, county_tiles, status = flown(COUNTY)
        peak_b = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak_b < 40e6  # a dense float32 layer of the county: 3.6 GB; its mask 900 MB
    assert status["cells_free"] == SIDE_M * SIDE_M
    g = county.grid
    assert g.frames == small.grid.frames > 10 and county_tiles and small_tiles
    assert g.nbytes < 4e6 and len(g.tile_keys()) <= 4
    # The square's cells (16..48 east, 0..64 north) in the county's grid.
    r0, c0 = -Y0_M, 16 - X0_M
    window = (r0, r0 + 64, c0, c0 + 32)
    for layer in LAYERS:
        np.testing.assert_array_equal(g.read(layer, window), small.grid.read(layer))
    observed = sum(int(np.count_nonzero(g.read(Layer.N_OBS, w))) for w in g.written_windows())
    assert status["cells_observed"] == observed > small_status["cells_observed"] > 0


def test_a_late_watcher_holds_the_county_grid_from_its_tiled_snapshot():
    """The county's snapshot is tiled (its free space and the tiles flown), a watcher
    joining late rebuilds the daemon's grid from it cell for cell in the memory of the
    tiles, follows the daemon's next tiles, and its figures are the daemon's status's."""
    live, _tiles, _ = flown(COUNTY)
    payload = encode_grid_snapshot(live.grid, live.tile_size, live.grid_hash)
    assert payload[:4] == b"PDSS" and len(payload) < 1e6
    tracemalloc.start()
    try:
        state = decode_grid_snapshot(payload, "pdcov/uav1/snapshot")
        peak_b = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak_b < 40e6 and state.nbytes < 4e6
    assert state.hash == live.grid_hash and state.frames == live.grid.frames
    assert state.n_free == SIDE_M * SIDE_M
    assert state.written_windows() == live.grid.written_windows()
    for window in live.grid.written_windows():
        for layer in LAYERS:
            np.testing.assert_array_equal(state.read(layer, window),
                                          live.grid.read(layer, window))
    w = Watcher(thresholds=(0.5, 0.8))
    w.on_snapshot("uav1", state, 0.0)
    feed(live, 4.0, 6.0)  # the flight goes on: its tiles follow the snapshot
    live.process()
    due = live.poll(6.0)
    assert due.tiles is not None
    w.on_tiles("uav1", decode_tiles(due.tiles), 1.0)
    doc = decode_status(encode_status(live.status_fields(uptime_s=6.0, seq=1, link={},
                                                         checkpoint={})))
    w.on_status("uav1", doc, 1.0)
    held = w.feeds["uav1"].state
    assert held is not None and held.frames == live.grid.frames
    for window in live.grid.written_windows():
        np.testing.assert_array_equal(held.read(Layer.LOG_MISS_D, window),
                                      live.grid.read(Layer.LOG_MISS_D, window))
    assert w.feeds["uav1"].status_agrees is True
    report = w.report(1.0).vehicles[0]
    assert report.proportion_at_or_above[0.5] == doc["proportion_at_or_above"]["0.5"] > 0


def test_a_tiled_snapshot_that_lies_is_refused_naming_why():
    """Bounded before it is parsed: a free space that does not give the grid hash, bytes
    after the last part, a part cut short, a declared free space longer than the payload,
    a grid beyond MAX_GRID_CELLS."""
    live, _tiles, _ = flown(COUNTY)
    good = encode_grid_snapshot(live.grid, live.tile_size, live.grid_hash)
    header = bytearray(good[:64])
    too_large = bytearray(header)
    n_wkb = int.from_bytes(good[52:56], "little")  # the header's fields: tiled_snapshot.py
    other = shapely.to_wkb(shapely.box(X0_M, Y0_M, X0_M + SIDE_M - 1, Y0_M + SIDE_M))
    lied = bytes(header[:52]) + len(other).to_bytes(4, "little") + good[56:64] + other \
        + good[64 + n_wkb:]
    too_large[44:48] = (2**20).to_bytes(4, "little")  # n_cols: 30,000 x 2**20 cells
    cases = {"the free space does not give the grid hash": lied,
             "free space: not WKB": good[:64] + bytes(n_wkb) + good[64 + n_wkb:],
             "bytes after the last part": good + b"\x00",
             "the payload ends": good[:-10],
             "more than 4194304 or than the payload holds":
                 good[:52] + (len(good)).to_bytes(4, "little") + good[56:],
             "more than 4294967296 cells": bytes(too_large) + good[64:]}
    for why, payload in cases.items():
        with pytest.raises(BusPayloadError, match=why):
            decode_grid_snapshot(payload, "pdcov/uav1/snapshot")


def test_a_county_recording_writes_the_tiles_flown(tmp_path):
    """`pdcov watch --record` of a county: each vehicle's grid and the fleet's written as
    their grid stores (the tiles flown, equal to the daemon's), the fleet's figures over
    the whole domain; with the mission config the report's outputs cropped to the extent
    flown."""
    live, _tiles, fields = flown(COUNTY)
    vid = fields["vehicle_id"]
    w = Watcher(thresholds=(0.5, 0.8))
    w.on_snapshot(vid, decode_grid_snapshot(
        encode_grid_snapshot(live.grid, live.tile_size, live.grid_hash)), 0.0)
    rec = Recording(tmp_path / "plain")
    lines = rec.finish(w, None)
    assert "wrote grid.zarr and metrics.json" in lines[-1], lines
    for folder in (vid, "fleet"):
        back = read_store_like(tmp_path / "plain" / folder / "grid.zarr", live.grid)
        assert back.tile_keys() == live.grid.tile_keys()
        for window in live.grid.written_windows():
            for layer in LAYERS:
                np.testing.assert_array_equal(back.read(layer, window),
                                              live.grid.read(layer, window))
    doc = json.loads((tmp_path / "plain" / "fleet" / "metrics.json").read_text())
    assert sum(doc["limiting_cells"].values()) == SIDE_M * SIDE_M
    assert doc["limiting_cells"] == live.grid.limiting_counts()
    assert doc["proportion_at_or_above"]["0.5"] == live.grid.metrics(
        [0.5]).proportion_at_or_above[0.5] > 0
    w.on_status(vid, decode_status(encode_status(fields)), 0.5)
    coverage = coverage_of(w)  # the exports written while recording: the extent flown
    assert coverage is not None and coverage.mask.size < 2e6
    assert coverage.pd.max() == max(live.grid.read(Layer.PD, window).max()
                                    for window in live.grid.written_windows())
    report = Recording(tmp_path / "report").finish(w, live.cfg.mission)
    metrics = json.loads((tmp_path / "report" / "fleet" / "metrics.json").read_text())
    assert metrics["cells_free"] == SIDE_M * SIDE_M and metrics["extent"]["cropped"], report
    assert (tmp_path / "report" / "fleet" / "grid.zarr").is_dir()
