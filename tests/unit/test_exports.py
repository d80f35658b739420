"""The exports for search teams' tools (report/exports.py, report/kml.py), read back by
independent readers in memory: strict JSON and shapely for the GeoJSON files (validity,
[lon, lat] order, the area outlined against the cells counted), fastkml and lxml against the
KML 2.2 structure, zipfile and PIL for the KMZ. GDAL's readers are in
test_exports_readers.py (e2e: they are processes)."""

from __future__ import annotations

import io
import json
import math
import zipfile

import numpy as np
import pytest
import shapely
from PIL import Image

from pdcov.core.geodesy import geodetic_to_enu
from pdcov.errors import OutputError
from pdcov.report.exports import VehicleDetections, caltopo_geojson, pins, write_exports
from pdcov.report.search_areas import map_layers
from tests.support.exports_fixtures import ORIGIN, coverage, detections_doc

KML = "{http://www.opengis.net/kml/2.2}"


def strict_json(path):
    def refuse(name):
        raise AssertionError(f"{path.name}: {name} is not JSON")
    return json.loads(path.read_text(), parse_constant=refuse)


@pytest.fixture()
def run(tmp_path):
    cov = coverage()
    result = write_exports(tmp_path, cov, [VehicleDetections.from_doc(detections_doc())],
                           title="test run")
    return tmp_path, cov, result


def enu_area(poly_lon_lat) -> shapely.Polygon:
    """A [lon, lat] polygon back in ENU m (so areas compare with cell counts)."""
    rings = []
    for ring in poly_lon_lat:
        a = np.asarray(ring)
        assert np.all(np.abs(a[:, 0] - ORIGIN.lon_deg) < 0.01), "lon first (RFC 7946)"
        assert np.all(np.abs(a[:, 1] - ORIGIN.lat_deg) < 0.01), "then lat"
        rings.append(geodetic_to_enu(a[:, 1], a[:, 0], ORIGIN.ground_alt_msl_m, ORIGIN)[:, :2])
    return shapely.Polygon(rings[0], rings[1:])


def test_every_file_is_written_and_named(run):
    out, _, result = run
    assert result.files == ("detections.geojson", "caltopo.geojson", "pd_overlay.png",
                            "pin_candidate.png", "pin_detection.png", "pdcov.kml",
                            "pdcov.kmz", "pdcov_atak.zip", "pdcov.gpx")
    assert result.not_written == ()
    assert all((out / f).is_file() for f in result.files)


def test_detections_geojson_has_a_point_per_detection_and_candidate(run):
    out, cov, _ = run
    doc = strict_json(out / "detections.geojson")
    assert doc["type"] == "FeatureCollection"
    feats = doc["features"]
    assert [f["properties"]["kind"] for f in feats] == ["candidate"] * 2 + ["detection"] * 3
    src = detections_doc()
    for f, d in zip(feats[2:], src["detections"], strict=True):
        assert f["geometry"]["type"] == "Point"
        lon, lat = f["geometry"]["coordinates"]  # RFC 7946: longitude first, no height
        assert (lon, lat) == pytest.approx((d["lon_deg"], d["lat_deg"]), abs=0.5e-7)
        p = f["properties"]
        assert {"vehicle", "t_boot_s", "class", "confidence", "looks", "hits", "pd"} <= set(p)
        assert p["vehicle"] == "alpha" and p["t_boot_s"] == d["t_boot_s"]
        assert p["pd"] == pytest.approx(cov.pd_at(d["x_m"], d["y_m"]), abs=1e-6)
    cand = feats[0]["properties"]
    assert (cand["hits"], cand["looks"], cand["candidate"]) == (9, 14, 3)
    assert (cand["uid"], cand["p_person"]) == ("alpha.3fa2c1.3", 0.9731)
    det = feats[4]["properties"]  # of pin 4: its figures
    assert (det["uid"], det["p_person"], det["looks"], det["hits"]) == (
        "alpha.3fa2c1.4", 0.0412, 3, 1)


def test_pd_is_the_payloads_without_a_grid_or_outside_the_free_cells():
    doc = detections_doc()
    doc["candidates"][1].update(x_m=-19.5)  # a western column: not free
    no_grid = pins([VehicleDetections.from_doc(doc)])
    assert [p.properties["pd"] for p in no_grid[:2]] == [0.6, 0.6]
    with_grid = pins([VehicleDetections.from_doc(doc)], coverage())
    assert with_grid[0].properties["pd"] != 0.6 and with_grid[1].properties["pd"] == 0.6


def test_caltopo_shapes_markers_and_assignments(run):
    out, cov, _ = run
    doc = strict_json(out / "caltopo.geojson")
    by_class: dict[str, list] = {}
    for f in doc["features"]:
        by_class.setdefault(f["properties"]["class"], []).append(f)
    assert set(by_class) == {"Shape", "Marker", "Assignment"}
    for f in by_class["Shape"] + by_class["Assignment"]:
        p = f["properties"]
        assert f["geometry"]["type"] == "Polygon"
        assert p["stroke"].startswith("#") and len(p["stroke"]) == 7
        assert 0 <= p["fill-opacity"] <= 1 and p["stroke-width"] > 0 and p["title"]
        assert enu_area(f["geometry"]["coordinates"]).is_valid
    for f in by_class["Assignment"]:
        assert f["properties"]["resourceType"] == "AIR"
        assert f["properties"]["status"] == "DRAFT"
    markers = by_class["Marker"]
    assert len(markers) == 2  # candidates only
    assert markers[0]["properties"]["marker-color"] == "FF0000"  # CalTopo writes no '#'
    assert markers[0]["properties"]["title"] == ("pin 1: person alpha.3fa2c1.3: p_person "
                                                 "0.97, detected 9 of 14 looks")
    assert {k: markers[1]["properties"][k] for k in ("uid", "p_person", "looks", "hits")} \
        == {"uid": "alpha.3fa2c1.4", "p_person": 0.0412, "looks": 3, "hits": 1}
    # The outlines cover exactly the free cells at or above each threshold (1 m cells), to
    # the vertices' rounding: 7 decimals move each by half 1e-7 deg, at most 5.6 mm.
    def assert_cells(features, cells) -> None:
        polys = [enu_area(f["geometry"]["coordinates"]) for f in features]
        assert sum(p.area for p in polys) == pytest.approx(
            int(cells.sum()), abs=5.6e-3 * sum(p.length for p in polys))

    for t in cov.thresholds:
        assert_cells([f for f in by_class["Shape"]
                      if f["properties"]["title"].startswith(f"P_D >= {t:g} ")],
                     cov.mask & (cov.pd >= t))
    gaps = [f for f in by_class["Shape"] if f["properties"]["title"].startswith("gap")]
    assert_cells(gaps, cov.mask & (cov.pd < cov.target_pd))
    assert doc["pdcov"]["gaps_total"] == len(gaps) == 2  # the west and the hole in the east


def test_gaps_are_bounded_largest_first(monkeypatch):
    from pdcov.report import search_areas

    monkeypatch.setattr(search_areas, "MAX_GAP_SHAPES", 10)
    cov = coverage()
    pd = np.ones_like(cov.pd)
    pd[::2, ::2] = 0.0  # hundreds of one-cell gaps ...
    pd[0:6, 20:30] = 0.0  # ... and a big one
    cov = type(cov)(pd, np.ones_like(cov.mask), cov.geometry, cov.origin, (0.8,), 0.8)
    layers = map_layers(cov)
    assert layers.gaps_total > 250 and len(layers.gaps) == 10
    assert enu_area(layers.gaps[0]).area > 50  # the big one first
    assert all(a.gap_cells >= 4 for a in layers.refly)


def test_each_refly_assignment_carries_the_pod_of_its_cells():
    # P_D 0.9 everywhere but a 4 x 4 hole of 0.1 (rows 10-13, columns 20-23): its re-fly
    # area is the hole grown by a cell, 6 x 6 cells, 20 of 0.9 round 16 of 0.1.
    cov = coverage()
    pd = np.full_like(cov.pd, 0.9)
    pd[10:14, 20:24] = 0.1
    cov = type(cov)(pd, np.ones_like(cov.mask), cov.geometry, cov.origin, (0.8,), 0.8)
    layers = map_layers(cov)
    [east] = layers.refly
    assert east.gap_cells == 16 and east.area_m2 == pytest.approx(36.0)
    assert east.pod == pytest.approx((20 * 0.9 + 16 * 0.1) / 36)  # 0.5444
    doc = caltopo_geojson(layers, [], "t")
    [feat] = [f for f in doc["features"] if f["properties"].get("class") == "Assignment"
              and f["properties"]["area_m2"] == round(east.area_m2)]
    assert feat["properties"]["pod"] == round(east.pod, 4)
    assert f"POD so far {east.pod:.2f}" in feat["properties"]["description"]


def test_kml_reads_as_kml_2_2_with_fastkml_and_lxml(run):
    from fastkml import kml
    from lxml import etree

    out, cov, _ = run
    data = (out / "pdcov.kml").read_bytes()
    root = etree.fromstring(data)
    assert root.tag == f"{KML}kml"
    doc = root.find(f"{KML}Document")
    folders = {f.findtext(f"{KML}name"): f for f in doc.findall(f"{KML}Folder")}
    assert set(folders) == {"P_D overlay", "P_D >= 0.5", "P_D >= 0.8", "gaps (P_D < 0.8)",
                            "re-fly areas", "candidates", "detections"}
    box = folders["P_D overlay"].find(f"{KML}GroundOverlay/{KML}LatLonBox")
    north, south, east, west = (float(box.findtext(f"{KML}{k}"))
                                for k in ("north", "south", "east", "west"))
    # The box is the grid's extent: 30 m north-south, 40 m east-west.
    (s_lat, w_lon), (n_lat, e_lon) = (
        (geodetic_to_enu(np.array([lat]), np.array([lon]), 600.0, ORIGIN)[0, :2])
        for lat, lon in ((south, west), (north, east)))
    assert (s_lat, w_lon, n_lat, e_lon) == pytest.approx((-20.0, -15.0, 20.0, 15.0), abs=0.01)
    cands = folders["candidates"].findall(f"{KML}Placemark")
    assert len(cands) == 2
    lon, lat = map(float, cands[0].findtext(f"{KML}Point/{KML}coordinates").split(","))
    assert (lon, lat) == pytest.approx((detections_doc()["candidates"][0]["lon_deg"],
                                        detections_doc()["candidates"][0]["lat_deg"]))
    data_names = {d.get("name") for d in cands[0].iter(f"{KML}Data")}
    assert {"vehicle", "hits", "looks", "pd", "class"} <= data_names
    # fastkml, a KML library of its own, reads the same document.
    k = kml.KML.from_string(data)
    (document,) = k.features
    names = [f.name for f in document.features]
    assert "candidates" in names and "P_D overlay" in names
    overlay = next(f for f in document.features if f.name == "P_D overlay").features[0]
    assert overlay.lat_lon_box.north == pytest.approx(north)


def test_kmz_holds_doc_kml_first_and_the_overlay_it_names(run):
    out, cov, _ = run
    with zipfile.ZipFile(out / "pdcov.kmz") as z:
        names = z.namelist()
        assert names == ["doc.kml", "pd_overlay.png", "pin_candidate.png", "pin_detection.png"]
        assert z.read("doc.kml") == (out / "pdcov.kml").read_bytes()
        png = Image.open(io.BytesIO(z.read("pd_overlay.png")))
    assert png.mode == "RGBA" and png.size == (40, 30)
    a = np.asarray(png)
    assert (a[:, :2, 3] == 0).all() and (a[:, 2:, 3] > 0).all()  # not free: transparent
    # North up: the image's top row is the grid's last (northern) row; the hole's rows
    # 10..13 from the south are image rows 16..19.
    assert not np.array_equal(a[16, 35], a[16, 39]) and np.array_equal(a[16, 35], a[19, 36])


def test_without_a_grid_only_the_detections_are_exported(tmp_path):
    result = write_exports(tmp_path, None, [VehicleDetections.from_doc(detections_doc())],
                           title="no grid yet")
    assert result.files == ("detections.geojson", "caltopo.geojson", "pin_candidate.png",
                            "pin_detection.png", "pdcov.kml", "pdcov.gpx")
    classes = {f["properties"]["class"]
               for f in strict_json(tmp_path / "caltopo.geojson")["features"]}
    assert classes == {"Marker"}


def test_missing_extras_are_named_and_the_rest_written(tmp_path, monkeypatch):
    import sys

    for module in ("matplotlib", "rasterio", "gpxpy", "mgrs"):
        monkeypatch.setitem(sys.modules, module, None)
    result = write_exports(tmp_path, coverage(), [VehicleDetections.from_doc(detections_doc())],
                           title="base install")
    assert result.files == ("detections.geojson", "caltopo.geojson", "pin_candidate.png",
                            "pin_detection.png", "pdcov.kml")
    assert any("rasterio" in line and "pip install 'pdcov[gis]'" in line
               for line in result.not_written)
    assert any(line.startswith("pd_overlay.png, pdcov.kmz") and "matplotlib" in line
               for line in result.not_written)
    assert "pdcov.gpx: the GPX export needs gpxpy: pip install 'pdcov[gis]'" in \
        result.not_written
    assert ("the pins' mgrs and utm properties (null): MGRS and UTM references need mgrs: "
            "pip install 'pdcov[gis]'") in result.not_written
    feats = strict_json(tmp_path / "detections.geojson")["features"]
    assert len(feats) == 5 and all(
        f["properties"]["mgrs"] is None and f["properties"]["utm"] is None for f in feats)


def test_a_file_that_cannot_be_written_is_one_error_naming_it(tmp_path):
    (tmp_path / "caltopo.geojson").mkdir()  # a folder where the file goes
    with pytest.raises(OutputError, match="caltopo.geojson"):
        write_exports(tmp_path, coverage(), [], title="t")
    assert json.loads((tmp_path / "detections.geojson").read_text())["features"] == []


def test_overlay_of_a_large_grid_is_bounded(monkeypatch):
    from pdcov.report import kml

    monkeypatch.setattr(kml, "MAX_OVERLAY_SIDE", 16)
    o = kml.overlay_png(coverage())
    w, h = Image.open(io.BytesIO(o.png)).size
    assert max(w, h) <= 16 and w == math.ceil(40 / 3)
