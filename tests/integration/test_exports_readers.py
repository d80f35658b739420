"""The exports read by GDAL (ogrinfo / ogr2ogr from Debian's gdal-bin, which .ci/run
installs): its GeoJSON driver for detections.geojson and caltopo.geojson, its LIBKML driver
for pdcov.kml and pdcov.kmz, each giving back the features and the [lon, lat] written."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import pytest

from pdcov.report.exports import VehicleDetections, write_exports
from tests.support.exports_fixtures import coverage, detections_doc

pytestmark = pytest.mark.skipif(shutil.which("ogr2ogr") is None,
                                reason="needs GDAL's ogrinfo and ogr2ogr (apt-get install "
                                       "gdal-bin; .ci/run does)")


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    out = tmp_path_factory.mktemp("exports")
    write_exports(out, coverage(), [VehicleDetections.from_doc(detections_doc())],
                  title="gdal")
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
    assert pin["Name"] == "person alpha.3fa2c1.3: p_person 0.97, detected 9 of 14 looks"
    assert "uid: alpha.3fa2c1.3" in pin["description"]
    assert "p_person: 0.9731" in pin["description"]
    assert (pin["uid"], float(pin["p_person"]), int(pin["looks"]), int(pin["hits"])) == (
        "alpha.3fa2c1.3", 0.9731, 14, 9)
    gaps = as_geojson(str(out / name), "gaps (P_D < 0.8)")["features"]
    assert len(gaps) == 2 and all(f["geometry"]["type"] == "Polygon" for f in gaps)
