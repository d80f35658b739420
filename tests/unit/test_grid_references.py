"""MGRS and UTM references of the pins (core/geodesy.grid_references): a point checked by
hand (on a zone's central meridian the easting is the false easting and the northing k0
times the meridian arc, integrated here), others against PROJ's UTM (rasterio.warp, GDAL's
PROJ: not NGA's GEOTRANS, which mgrs wraps) to the metre, the reference read back by mgrs;
and the references on every pin of detections.geojson, the CalTopo markers, the KML
placemarks' ExtendedData and the CoT remarks."""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET

import mgrs
import pytest
from rasterio.crs import CRS
from rasterio.warp import transform
from scipy.integrate import quad

from pdcov.core.geodesy import Origin, geodetic_to_enu, grid_references
from pdcov.report.cot_events import candidate_event
from pdcov.report.exports import VehicleDetections, write_exports
from tests.support.exports_fixtures import candidate, coverage, detections_doc

A_M, F = 6378137.0, 1 / 298.257223563  # WGS84
K0 = 0.9996  # UTM's scale on the central meridian
KML = "{http://www.opengis.net/kml/2.2}"


def meridian_arc_m(lat_deg: float) -> float:
    """Distance along the WGS84 meridian from the equator, by integrating its radius of
    curvature a (1 - e²) / (1 - e² sin² phi)^(3/2)."""
    e2 = F * (2 - F)
    arc, _ = quad(lambda p: A_M * (1 - e2) / (1 - e2 * math.sin(p) ** 2) ** 1.5, 0.0,
                  math.radians(lat_deg), epsabs=1e-6)
    return arc


def test_a_point_on_a_central_meridian_checked_by_hand():
    # mgrs's own documentation: 42 N 93 W is 15TWG0000049776. 93 W is the central meridian
    # of zone 15 (96 W to 90 W): easting 500,000 m; band T is 40 N to 48 N.
    ref, utm = grid_references(42.0, -93.0)
    assert ref == "15T WG 00000 49776"
    assert utm == "15T 500000 4649776"
    assert math.floor(K0 * meridian_arc_m(42.0)) == 4649776


@pytest.mark.parametrize(("lat", "lon", "zone"), [
    (46.5002, 7.2502, "32T"),  # the export fixtures' origin
    (-33.9249, 18.4241, "34H"),  # the southern hemisphere: false northing 10,000 km
    (60.0, 5.5, "32V"),  # Norway's exception: zone 32, not 31
    (0.0001, 2.9999, "31N"),  # the equator, a zone's eastern edge
    (37.7749, -122.4194, "10S"),
])
def test_utm_agrees_with_proj_to_the_metre_and_mgrs_reads_back(lat, lon, zone):
    ref, utm = grid_references(lat, lon)
    assert ref.startswith(f"{zone} ") and utm is not None
    z, east, north = utm.split()
    assert z == zone
    epsg = (32600 if lat >= 0 else 32700) + int(zone[:-1])
    (e,), (n,) = transform(CRS.from_epsg(4326), CRS.from_epsg(epsg), [lon], [lat])
    # The 1 m square holding the point: its corner, 0 to 1 m below PROJ's (1 mm leeway
    # between the two implementations).
    assert -1e-3 <= e - int(east) < 1 + 1e-3 and -1e-3 <= n - int(north) < 1 + 1e-3
    square, digits_e, digits_n = ref.split()[1:]
    assert len(square) == 2 and digits_e == east[-5:].zfill(5) and \
        digits_n == north[-5:].zfill(5)
    back_lat, back_lon = mgrs.MGRS().toLatLon(ref)  # spaced, as written
    d = geodetic_to_enu(back_lat, back_lon, 0.0, Origin(lat, lon))[:2]
    assert math.hypot(*d) < 1.5  # within the 1 m square's diagonal


def test_polar_points_have_an_mgrs_but_no_utm_and_nonsense_is_refused():
    ref, utm = grid_references(89.0, 45.0)
    assert ref.startswith("Z ") and utm is None  # UPS north
    with pytest.raises(ValueError, match="no MGRS reference"):
        grid_references(91.0, 0.0)


def test_every_pin_of_every_export_carries_its_references(tmp_path):
    src = detections_doc()
    write_exports(tmp_path, coverage(), [VehicleDetections.from_doc(src)], title="refs")
    expected = [grid_references(p["lat_deg"], p["lon_deg"])
                for p in src["candidates"] + src["detections"]]
    feats = json.loads((tmp_path / "detections.geojson").read_text())["features"]
    assert [(f["properties"]["mgrs"], f["properties"]["utm"]) for f in feats] == expected
    assert expected[0] == ("32T LS 65735 51092", "32T 365735 5151092")
    markers = [f["properties"] for f in json.loads(
        (tmp_path / "caltopo.geojson").read_text())["features"]
        if f["properties"]["class"] == "Marker"]
    assert [(m["mgrs"], m["utm"]) for m in markers] == expected[:2]
    assert "mgrs: 32T LS 65735 51092" in markers[0]["description"]
    root = ET.parse(tmp_path / "pdcov.kml").getroot()
    placemarks = list(root.iter(f"{KML}Placemark"))
    data = [{d.get("name"): d.findtext(f"{KML}value") for d in pm.iter(f"{KML}Data")}
            for pm in placemarks if pm.find(f"{KML}Point") is not None]
    assert [(d["mgrs"], d["utm"]) for d in data] == expected


def test_the_cot_remarks_give_the_references():
    c = candidate(3, 15.4, 2.2)
    ref, utm = grid_references(c["lat_deg"], c["lon_deg"])
    remarks = ET.fromstring(candidate_event("uav1", c, 1.7e9, 300.0)).findtext(
        "detail/remarks")
    assert remarks.endswith(f"; {c['alt_msl_m']:.1f} m MSL; MGRS {ref}; UTM {utm}")
