"""The exports read by GDAL (ogrinfo / ogr2ogr from Debian's gdal-bin, which .ci/run
installs): its GeoJSON driver for detections.geojson and caltopo.geojson, its LIBKML driver
for pdcov.kml and pdcov.kmz, its GPX driver for pdcov.gpx, each giving back the features,
the [lon, lat] written and the pins' MGRS and UTM references."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from pdcov.core.geodesy import enu_to_geodetic, grid_references
from pdcov.report.exports import TrackSegment, VehicleDetections, VehicleTrack, write_exports
from tests.support.exports_fixtures import ORIGIN, coverage, detections_doc

FLIGHTS = [np.c_[np.linspace(-20.0, 20.0, 9), np.zeros(9), np.full(9, 30.0)],
           np.c_[np.zeros(5), np.linspace(-10.0, 10.0, 5), np.full(5, 40.0)]]
"""Two flights of vehicle alpha, ENU m about ORIGIN: the first at known times, one a
second from T0, the second not."""
T0 = 1_767_225_600.25  # 2026-01-01T00:00:00.25Z

pytestmark = pytest.mark.skipif(shutil.which("ogr2ogr") is None,
                                reason="needs GDAL's ogrinfo and ogr2ogr (apt-get install "
                                       "gdal-bin; .ci/run does)")


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    out = tmp_path_factory.mktemp("exports")
    write_exports(out, coverage(), [VehicleDetections.from_doc(detections_doc())],
                  title="gdal", tracks=[VehicleTrack("alpha", (
                      TrackSegment(enu_to_geodetic(FLIGHTS[0], ORIGIN), T0 + np.arange(9)),
                      *VehicleTrack.from_enu("alpha", FLIGHTS[1:], ORIGIN).segments))])
    return out


def ogrinfo(*args: str) -> str:
    return subprocess.run(["ogrinfo", "-ro", "-so", *args], capture_output=True, text=True,
                          check=True, timeout=60).stdout


def as_geojson(src: str, layer: str | None = None) -> dict:
    cmd = ["ogr2ogr", "-f", "GeoJSON", "/vsistdout/", src, *([layer] if layer else [])]
    return json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True,
                                     timeout=60).stdout)


def counts(text: str) -> list[int]:
    return [int(n) for n in re.findall(r"Feature Count: (\d+)", text)]


def test_gdal_reads_the_geojson_exports(out):
    info = ogrinfo("-al", str(out / "detections.geojson"))
    assert "using driver `GeoJSON' successful" in info and counts(info) == [5]
    assert "Geometry: Point" in info and 'GEOGCRS["WGS 84"' in info
    back = as_geojson(str(out / "detections.geojson"))
    src = detections_doc()["candidates"][0]
    assert back["features"][0]["geometry"]["coordinates"] == pytest.approx(
        [src["lon_deg"], src["lat_deg"]], abs=0.5e-7)
    assert [(f["properties"]["mgrs"], f["properties"]["utm"]) for f in back["features"]] \
        == [grid_references(p["lat_deg"], p["lon_deg"])
            for p in detections_doc()["candidates"] + detections_doc()["detections"]]
    figures = [{k: f["properties"][k] for k in ("uid", "p_person", "looks", "hits")}
               for f in back["features"]]
    assert figures[1] == figures[4] == {"uid": "alpha.3fa2c1.4", "p_person": 0.0412,
                                        "looks": 3, "hits": 1}  # pin 4 and its detection
    info = ogrinfo("-al", str(out / "caltopo.geojson"))
    assert "using driver `GeoJSON' successful" in info
    doc = json.loads((out / "caltopo.geojson").read_text())
    assert counts(info) == [len(doc["features"])]
    caltopo = as_geojson(str(out / "caltopo.geojson"))["features"]
    assert {f["properties"]["class"] for f in caltopo} == {"Shape", "Marker", "Assignment"}
    markers = [f["properties"] for f in caltopo if f["properties"]["class"] == "Marker"]
    assert [(m["uid"], m["p_person"], m["looks"], m["hits"]) for m in markers] == [
        ("alpha.3fa2c1.3", 0.9731, 14, 9), ("alpha.3fa2c1.4", 0.0412, 3, 1)]


@pytest.mark.parametrize("name", ["pdcov.kml", "pdcov.kmz"])
def test_gdal_libkml_reads_the_kml_and_kmz(out, name):
    info = ogrinfo(str(out / name))
    assert "using driver `LIBKML' successful" in info
    layers = re.findall(r"^\d+: (.+)$", info, flags=re.M)
    assert layers == ["P_D overlay", "P_D >= 0.5", "P_D >= 0.8", "gaps (P_D < 0.8)",
                      "re-fly areas", "candidates", "detections"]
    cands = as_geojson(str(out / name), "candidates")["features"]
    src = detections_doc()["candidates"]
    assert [f["geometry"]["coordinates"][:2] for f in cands] == [
        pytest.approx([c["lon_deg"], c["lat_deg"]], abs=0.5e-7) for c in src]
    pin = cands[0]["properties"]  # LIBKML: the name, description and ExtendedData fields
    assert pin["Name"] == "pin 1: person alpha.3fa2c1.3: p_person 0.97, detected 9 of 14 looks"
    assert "uid: alpha.3fa2c1.3" in pin["description"]
    assert "p_person: 0.9731" in pin["description"]
    assert (pin["uid"], float(pin["p_person"]), int(pin["looks"]), int(pin["hits"])) == (
        "alpha.3fa2c1.3", 0.9731, 14, 9)
    assert (pin["mgrs"], pin["utm"]) == grid_references(src[0]["lat_deg"], src[0]["lon_deg"])
    gaps = as_geojson(str(out / name), "gaps (P_D < 0.8)")["features"]
    assert len(gaps) == 2 and all(f["geometry"]["type"] == "Polygon" for f in gaps)


def test_gdal_gpx_reads_the_tracks_and_waypoints(out):
    info = ogrinfo(str(out / "pdcov.gpx"))
    assert "using driver `GPX' successful" in info
    layers = re.findall(r"^\d+: (\S+)", info, flags=re.M)
    assert layers == ["waypoints", "routes", "tracks", "route_points", "track_points"]
    wpts = as_geojson(str(out / "pdcov.gpx"), "waypoints")["features"]
    src = detections_doc()["candidates"]
    assert [(f["properties"]["name"], f["properties"]["ele"], f["geometry"]["coordinates"])
            for f in wpts] == [(c["uid"], pytest.approx(c["alt_msl_m"]), pytest.approx(
                [c["lon_deg"], c["lat_deg"]], abs=0.5e-7)) for c in src]
    assert "detected 9 of 14 looks; sigma 0.5 m; MGRS 32T" in wpts[0]["properties"]["desc"]
    (trk,) = as_geojson(str(out / "pdcov.gpx"), "tracks")["features"]
    assert trk["properties"]["name"] == "alpha"
    assert trk["geometry"]["type"] == "MultiLineString"  # a line per flight
    pts = as_geojson(str(out / "pdcov.gpx"), "track_points")["features"]
    assert [p["properties"]["track_seg_id"] for p in pts] == [0] * 9 + [1] * 5
    lla = np.concatenate([enu_to_geodetic(f, ORIGIN) for f in FLIGHTS])
    assert [p["geometry"]["coordinates"] for p in pts] == [
        pytest.approx([lon, lat], abs=0.5e-7) for lat, lon, _ in lla]
    assert [p["properties"]["ele"] for p in pts] == pytest.approx(lla[:, 2], abs=0.005)
    times = [p["properties"].get("time") for p in pts]
    assert times[:2] == ["2026-01-01T00:00:00.250Z", "2026-01-01T00:00:01.250Z"]
    assert times[9:] == [None] * 5  # no real time known
