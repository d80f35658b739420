"""The exports' conventions (report/exports.py, report/kml.py, report/gis.py), each checked
on the files written by a computation of its own: every polygon wound as RFC 7946 wants
(the signed area by the shoelace formula), latitudes and longitudes to 7 decimals
(geodesy.DEG_DECIMALS), KML and KMZ with no reference to the internet (every file they
name beside the KML and inside the KMZ), and a pin's "detected N of M looks" with N <= M
when the detector boxes it in more frames than its cell has counted looks."""

from __future__ import annotations

import io
import json
import re
import xml.etree.ElementTree as ET
import zipfile

import numpy as np
import pytest
from PIL import Image

from pdcov.bus.detections import decode_detections, detections_document, encode_detections
from pdcov.core.camera import CameraModel
from pdcov.core.detections import Box
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain, GridGeometry
from pdcov.core.geodesy import DEG_DECIMALS
from pdcov.core.geolocate import Geolocation
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import FixedMount, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx
from pdcov.detection.candidates import DetectionTracker
from pdcov.report.exports import VehicleDetections, write_exports
from pdcov.report.gis import threshold_outline, write_outline_geojson
from pdcov.report.kml import ICON_PX, ICONS
from pdcov.report.search_areas import Coverage
from tests.support.exports_fixtures import ORIGIN, coverage, detections_doc

KML = "{http://www.opengis.net/kml/2.2}"


def ring_gaps() -> Coverage:
    """60 x 60 cells of 1 m, all free, P_D 1 but a square ring 4 cells wide of P_D 0.2: a
    gap with a hole, a re-fly area with a hole, an outline with a hole and an island in
    it."""
    pd = np.ones((60, 60))
    pd[10:50, 10:50] = 0.2
    pd[14:46, 14:46] = 1.0
    return Coverage(pd, np.ones((60, 60), bool), GridGeometry(-30.0, -30.0, 1.0, 60, 60),
                    ORIGIN, (0.5, 0.8), 0.8)


def written(tmp_path, cov: Coverage) -> None:
    """The exports and outline.geojson (as report/outputs.py writes it) of ``cov``."""
    write_exports(tmp_path, cov, [VehicleDetections.from_doc(detections_doc())], title="t")
    write_outline_geojson(tmp_path / "outline.geojson",
                          threshold_outline(cov.pd, cov.mask, cov.geometry, 0.8), cov.origin,
                          0.8)


def shoelace(ring) -> float:
    """Twice the signed area of a closed ring of [x, y]: positive when counter-clockwise
    (x east, y north)."""
    return sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(ring, ring[1:], strict=False))


def polygons_written(out) -> dict[str, list]:
    """Every polygon (its rings of [lon, lat]) in the files, by file and class."""
    found: dict[str, list] = {}
    for f in json.loads((out / "caltopo.geojson").read_text())["features"]:
        if f["geometry"]["type"] == "Polygon":
            found.setdefault(f"caltopo {f['properties']['class']}", []).append(
                f["geometry"]["coordinates"])
    (outline,) = json.loads((out / "outline.geojson").read_text())["features"]
    found["outline"] = outline["geometry"]["coordinates"]
    for pm in ET.parse(out / "pdcov.kml").getroot().iter(f"{KML}Polygon"):
        rings = [[[float(v) for v in p.split(",")] for p in c.text.split()]
                 for c in pm.iter(f"{KML}coordinates")]
        found.setdefault("kml", []).append(rings)
    return found


@pytest.mark.parametrize("cov", [coverage, ring_gaps])
def test_every_polygon_is_counter_clockwise_and_every_hole_clockwise(tmp_path, cov):
    written(tmp_path, cov())
    found = polygons_written(tmp_path)
    assert set(found) == {"caltopo Shape", "caltopo Assignment", "outline", "kml"}
    for where, polys in found.items():
        for k, (exterior, *holes) in enumerate(polys):
            assert shoelace(exterior) > 0, f"{where} {k}: exterior clockwise"
            assert all(shoelace(h) < 0 for h in holes), f"{where} {k}: a hole anticlockwise"
    assert any(len(p) > 1 for p in found["outline"])  # holes were checked
    if cov is ring_gaps:  # the re-fly area around the covered middle has it as a hole
        (refly,) = found["caltopo Assignment"]
        assert len(refly) == 2


def test_latitudes_and_longitudes_have_7_decimals(tmp_path):
    written(tmp_path, coverage())

    def numbers(v):
        if isinstance(v, list):
            for x in v:
                yield from numbers(x)
        else:
            yield v

    for name in ("detections.geojson", "caltopo.geojson", "outline.geojson"):
        feats = json.loads((tmp_path / name).read_text())["features"]
        coords = list(numbers([f["geometry"]["coordinates"] for f in feats]))
        assert coords and all(round(v, DEG_DECIMALS) == v for v in coords), name
        assert any(round(v, DEG_DECIMALS - 1) != v for v in coords), name  # not fewer
    root = ET.parse(tmp_path / "pdcov.kml").getroot()
    texts = [p for c in root.iter(f"{KML}coordinates") for p in c.text.replace(",", " ").split()]
    texts += [root.find(f".//{KML}LatLonBox/{KML}{k}").text for k in ("north", "west")]
    assert texts and all(re.fullmatch(r"-?\d+\.\d{7}", t) for t in texts)
    # A candidate lands within half the last decimal of where it was.
    src = detections_doc()["candidates"][0]
    first = json.loads((tmp_path / "detections.geojson").read_text())["features"][0]
    assert first["geometry"]["coordinates"] == pytest.approx(
        [src["lon_deg"], src["lat_deg"]], abs=0.5e-7)


def test_kml_and_kmz_name_no_internet_address_and_hold_every_file_they_name(tmp_path):
    from fastkml.validator import validate

    written(tmp_path, coverage())
    assert validate(file_to_validate=tmp_path / "pdcov.kml")  # OGC KML 2.2's schema
    kml = (tmp_path / "pdcov.kml").read_bytes()
    with zipfile.ZipFile(tmp_path / "pdcov.kmz") as z:
        inside = {n: z.read(n) for n in z.namelist()}
    assert inside["doc.kml"] == kml
    root = ET.fromstring(kml)
    values = [v for e in root.iter() for v in (e.text or "", *e.attrib.values())]
    assert not [v for v in values if "://" in v or v.strip().startswith("www.")]
    hrefs = {e.text for e in root.iter(f"{KML}href")}
    assert hrefs == {"pd_overlay.png", *(name for name, _ in ICONS.values())}
    for href in hrefs:
        beside = (tmp_path / href).read_bytes()
        assert inside[href] == beside  # the KMZ holds it, the KML finds it beside it
        Image.open(io.BytesIO(beside)).verify()
    for kind, (name, color) in ICONS.items():
        icon = Image.open(tmp_path / name)
        assert icon.mode == "RGBA" and icon.size == (ICON_PX, ICON_PX)
        rgb = tuple(int(color[i:i + 2], 16) for i in (1, 3, 5))
        assert icon.getpixel((ICON_PX // 2, ICON_PX // 2)) == (*rgb, 255), kind
        assert icon.getpixel((0, 0))[3] == 0  # transparent around the disc
        style = root.find(f".//{KML}Style[@id='{kind}']/{KML}IconStyle")
        assert style.findtext(f"{KML}Icon/{KML}href") == name


def test_a_pin_boxed_in_every_frame_says_at_most_one_hit_a_look(tmp_path):
    """A person under a camera at 5 frames a second on a 1 s revisit clock, boxed in all
    20 frames: 4 counted looks, so "detected 4 of 4 looks", never "20 of 4"."""
    f_px, h_m = 500.0, 10.0
    camera = CameraModel(640, 480, np.array([[f_px, 0, 319.5], [0, f_px, 239.5], [0, 0, 1]]))
    dom = Domain.from_enu([[-20, -20], [20, -20], [20, 20], [-20, 20]])
    geo = dom.grid_geometry(1.0)
    grid = CoverageGrid(geo, dom.free_mask(geo), camera, DetectorModel.illustrative(),
                        min_revisit_s=1.0)
    tracker = DetectionTracker(camera, Geolocation(pixel_sigma_px=1.0), 1.0,
                               uid_prefix="uav1.ab12cd.")
    person = Box("person", 0.8, 319.5 - 12.0, 239.5 - 50.0, 24.0, 50.0)  # feet under it
    detections = []
    for k in range(20):
        pose = fixed_mount_pose(R_from_euler_zyx(0.0, 0.0, 0.0), np.array([0.0, 0.0, h_m]),
                                FixedMount(), 0.2 * k)
        grid.update(pose)
        detections += tracker.frame(pose, 0.2 * k, [person], grid=grid)
    (cand,) = tracker.candidates(grid)
    assert len(detections) == 20 and (cand.hits, cand.looks) == (4, 4)
    doc = decode_detections(encode_detections(detections_document(
        detections, [cand], ORIGIN, "uav1")))  # as the watcher receives it
    write_exports(tmp_path, grid_coverage(grid), [VehicleDetections.from_doc(doc)],
                  title="t")
    (marker,) = [f["properties"] for f in json.loads(
        (tmp_path / "caltopo.geojson").read_text())["features"]
        if f["properties"]["class"] == "Marker"]
    names = [pm.findtext(f"{KML}name") for pm in ET.parse(tmp_path / "pdcov.kml").getroot()
             .iter(f"{KML}Placemark") if pm.findtext(f"{KML}styleUrl") == "#candidate"]
    for title in (marker["title"], *names):
        hits, looks = map(int, re.search(r"detected (\d+) of (\d+) looks", title).groups())
        assert hits <= looks and (hits, looks) == (4, 4), title


def grid_coverage(grid: CoverageGrid) -> Coverage:
    return Coverage(grid.pd, grid.mask, grid.geometry, ORIGIN, (0.5,), 0.5)
