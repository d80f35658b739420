"""The exports read by GDAL (ogrinfo / ogr2ogr from Debian's gdal-bin, which .ci/run
installs): its GeoJSON driver for detections.geojson and caltopo.geojson, its LIBKML driver
for pdcov.kml and pdcov.kmz, each giving back the features and the [lon, lat] written."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import pytest
from exports_fixtures import coverage, detections_doc

from pdcov.report.exports import VehicleDetections, write_exports

pytestmark = [pytest.mark.e2e,
              pytest.mark.skipif(shutil.which("ogr2ogr") is None,
                                 reason="needs GDAL's ogrinfo and ogr2ogr (apt-get install "
                                        "gdal-bin; .ci/run does)")]


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
        [src["lon_deg"], src["lat_deg"]], abs=1e-9)
    info = ogrinfo("-al", str(out / "caltopo.geojson"))
    assert "using driver `GeoJSON' successful" in info
    doc = json.loads((out / "caltopo.geojson").read_text())
    assert counts(info) == [len(doc["features"])]
    classes = {f["properties"]["class"] for f in as_geojson(str(out / "caltopo.geojson"))
               ["features"]}
    assert classes == {"Shape", "Marker", "Assignment"}


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
        pytest.approx([c["lon_deg"], c["lat_deg"]], abs=1e-9) for c in src]
    gaps = as_geojson(str(out / name), "gaps (P_D < 0.8)")["features"]
    assert len(gaps) == 2 and all(f["geometry"]["type"] == "Polygon" for f in gaps)
