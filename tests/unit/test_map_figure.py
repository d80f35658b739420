"""The handover map (report/map_figure.py) and the pins' ranks (report/pin_rank.py): web
Mercator tile numbers by hand, the basemap sampled at the right tile pixel, bounded tile
reads, ranks by p_person in every export."""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest

from pdcov.core.domain import Domain
from pdcov.report.exports import VehicleDetections, VehicleTrack, pins, write_exports
from pdcov.report.map_figure import (
    BasemapTiles,
    basemap_rgb,
    map_figure,
    web_mercator_tile_xy,
)
from pdcov.report.pin_rank import candidate_ranks
from tests.support.exports_fixtures import ORIGIN, candidate, coverage, detections_doc

pytest.importorskip("matplotlib")
from PIL import Image


def png(rgb: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(rgb.astype(np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def test_tile_numbers_by_hand():
    # Zoom 1: four tiles; (0 N, 0 E) is their common corner.
    tx, ty = web_mercator_tile_xy(np.array(0.0), np.array(0.0), 1)
    assert (float(tx), float(ty)) == pytest.approx((1.0, 1.0))
    # The web Mercator's top edge is 85.0511 N; 180 W the left edge.
    tx, ty = web_mercator_tile_xy(np.array(85.0511287798), np.array(-180.0), 3)
    assert (float(tx), float(ty)) == pytest.approx((0.0, 0.0), abs=1e-6)
    # 46.5 N 7.25 E at zoom 10: x = 187.25 / 360 x 1024 = 532.62;
    # y = (1 - asinh(tan 46.5 deg) / pi) / 2 x 1024 = (1 - 0.91890 / pi) / 2 x 1024
    # = 362.24 (OpenStreetMap's slippy-map formula), so tile 532/362.
    tx, ty = web_mercator_tile_xy(np.array(46.5), np.array(7.25), 10)
    assert float(tx) == pytest.approx(532.622, abs=1e-3)
    assert float(ty) == pytest.approx(
        (1 - math.asinh(math.tan(math.radians(46.5))) / math.pi) / 2 * 1024, abs=1e-9)
    assert float(ty) == pytest.approx(362.24, abs=0.01)


def coded_tiles(z: int, side: int = 256, calls: list | None = None) -> BasemapTiles:
    """Tiles whose red is x % 256, green y % 256, blue the pixel's column within the tile
    (x 4, capped): a sampled pixel says which tile and where."""
    def tile(zz: int, x: int, y: int) -> bytes | None:
        if calls is not None:
            calls.append((zz, x, y))
        img = np.zeros((side, side, 3), np.uint8)
        img[..., 0], img[..., 1] = x % 256, y % 256
        img[..., 2] = np.minimum(np.arange(side) * 256 // side, 255)[None, :]
        return png(img)
    return BasemapTiles(tile, (z,))


def test_the_basemap_is_sampled_at_the_right_tile_and_pixel():
    lat, lon = np.array([[46.5]]), np.array([[7.25]])
    rgb, z = basemap_rgb(coded_tiles(10), lat, lon, pixel_m=100.0)
    assert z == 10
    # Tile 532/362; within it x = 0.622 of the way across: column 159 of 256.
    assert tuple(rgb[0, 0]) == (532 % 256, 362 % 256, 159)


def test_the_zoom_nearest_the_pixel_is_taken_and_the_tiles_are_bounded():
    lat = np.linspace(46.4, 46.6, 50)[:, None] * np.ones((1, 50))
    lon = np.linspace(7.1, 7.4, 50)[None, :] * np.ones((50, 1))
    calls: list = []
    held = (8, 12, 16)
    tiles = BasemapTiles(coded_tiles(0, calls=calls).tile, held)
    # 600 m pixels want zoom 7.5 (156,543 cos 46.5 deg / 600 = 2^7.49): 8 is the nearest.
    _, z = basemap_rgb(tiles, lat, lon, pixel_m=600.0)
    assert z == 8
    # 2 m pixels want 15.7: 16 would take ~55 x 53 tiles over 0.3 x 0.2 deg, more than
    # MAX_BASEMAP_TILES; 12 takes 5 x 5.
    calls.clear()
    _, z = basemap_rgb(tiles, lat, lon, pixel_m=2.0)
    assert z == 12 and 0 < len(calls) <= 25


def test_bad_and_oversized_tiles_are_skipped():
    lat, lon = np.array([[46.5]]), np.array([[7.25]])
    big = png(np.zeros((1100, 8, 3)))
    for data in (b"not an image", big, None):
        rgb, _ = basemap_rgb(BasemapTiles(lambda z, x, y, d=data: d, (10,)), lat, lon, 100.0)
        assert rgb is None


def test_ranks_by_p_person_over_every_vehicle():
    a = VehicleDetections("a", candidates=(candidate(1, 0, 0, p_person=0.2, vehicle="a"),
                                           candidate(2, 0, 0, p_person=0.9, vehicle="a")))
    b = VehicleDetections("b", candidates=(candidate(1, 0, 0, p_person=0.5, vehicle="b"),
                                           {**candidate(2, 0, 0, vehicle="b"),
                                            "p_person": None}))
    ranks = candidate_ranks([a, b])
    assert ranks == {("a", "a.3fa2c1.2"): 1, ("b", "b.3fa2c1.1"): 2, ("a", "a.3fa2c1.1"): 3,
                     ("b", "b.3fa2c1.2"): 4}


def test_every_export_carries_the_rank(tmp_path):
    doc = detections_doc()
    write_exports(tmp_path, coverage(), [VehicleDetections.from_doc(doc)], title="t")
    feats = json.loads((tmp_path / "detections.geojson").read_text())["features"]
    by_kind = {(f["properties"]["kind"], f["properties"]["uid"]): f["properties"]["rank"]
               for f in feats}
    assert by_kind[("candidate", "alpha.3fa2c1.3")] == 1  # p_person 0.9731
    assert by_kind[("candidate", "alpha.3fa2c1.4")] == 2  # 0.0412
    assert by_kind[("detection", "alpha.3fa2c1.4")] == 2  # its candidate's
    caltopo = json.loads((tmp_path / "caltopo.geojson").read_text())["features"]
    assert sorted(f["properties"]["rank"] for f in caltopo
                  if f["properties"].get("class") == "Marker") == [1, 2]


def test_map_png_is_drawn_over_a_basemap_with_tracks_and_pins(tmp_path):
    cov = coverage()
    domain = Domain.from_enu([(-20, -15), (20, -15), (20, 15), (-20, 15)])
    track = VehicleTrack.from_enu("alpha", [np.c_[np.linspace(-18, 18, 10), np.zeros(10),
                                                  np.full(10, 30.0)]], ORIGIN)
    found = map_figure(tmp_path / "map.png", cov.pd, cov.mask, cov.geometry, domain, ORIGIN,
                       title="t", tracks=[track], pins=pins([VehicleDetections.from_doc(
                           detections_doc())]), basemap=coded_tiles(19))
    assert found
    img = np.asarray(Image.open(tmp_path / "map.png"))
    assert img.shape[0] > 500 and img.shape[1] > 500
    # Nowhere is there a basemap tile: drawn without it, and said.
    nowhere = BasemapTiles(lambda z, x, y: None, (19,))
    assert not map_figure(tmp_path / "map2.png", cov.pd, cov.mask, cov.geometry, domain,
                          ORIGIN, title="t", basemap=nowhere)
    assert (tmp_path / "map2.png").stat().st_size > 0

