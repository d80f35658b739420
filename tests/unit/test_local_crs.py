"""The GeoTIFFs' planes (report/gis.py). ``local_crs_wkt``, the plane they are warped from,
lies on the mission's ENU plane: a point of the plane, taken to latitude and longitude as
pdcov takes every point and projected by PROJ, lands at its ENU x, y, at sea level and at
an origin 2,500 m up. ``utm_epsg``: the zone by longitude, hemisphere by latitude, with the
Norway and Svalbard exceptions."""

import numpy as np
import pytest

rasterio = pytest.importorskip("rasterio")

from rasterio.warp import transform  # noqa: E402

from pdcov.core.geodesy import Origin, enu_to_geodetic  # noqa: E402
from pdcov.report.gis import local_crs_wkt, utm_epsg  # noqa: E402


@pytest.mark.parametrize("alt_m", [0.0, 2500.0])
def test_enu_points_project_to_their_enu_coordinates(alt_m):
    origin = Origin(46.5, 9.8, alt_m)
    enu = np.array([[2000.0, 2000.0, 0.0], [-1500.0, 500.0, 0.0], [0.0, -2000.0, 0.0]])
    geo = enu_to_geodetic(enu, origin)
    x, y = transform("EPSG:4326", local_crs_wkt(origin), geo[:, 1], geo[:, 0])
    # By hand: with scale 1 the 2,500 m origin's plane would land 2000 x 2500 / 6.38e6 =
    # 0.78 m short at 2 km; what is left is the plane's curvature, x^3 / (3 R^2) ~ 0.1 mm.
    np.testing.assert_allclose(x, enu[:, 0], atol=0.005)
    np.testing.assert_allclose(y, enu[:, 1], atol=0.005)


@pytest.mark.parametrize(("lat_deg", "lon_deg", "epsg"), [
    (39.35, -76.33, 32618), (45.0, 5.99, 32631), (45.0, 6.0, 32632), (-33.9, 151.2, 32756),
    (0.0, -180.0, 32601), (-0.001, 179.999, 32760), (45.0, 359.0, 32630),  # 359 E = 1 W
    (60.4, 5.3, 32632), (55.9, 5.3, 32631), (64.0, 5.3, 32631), (60.0, 2.9, 32631),  # Norway
    (78.2, 15.6, 32633), (78.0, 8.9, 32631), (78.0, 9.0, 32633), (78.0, 33.0, 32637),
    (71.9, 15.6, 32633), (80.0, 42.0, 32638)])  # Svalbard and beyond it
def test_utm_zone_of_the_origin(lat_deg, lon_deg, epsg):
    assert utm_epsg(Origin(lat_deg, lon_deg)) == epsg
