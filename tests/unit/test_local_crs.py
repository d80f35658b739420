"""pd.tif's CRS (report/gis.py ``local_crs_wkt``) lies on the mission's ENU plane: a point of
the plane, taken to latitude and longitude as pdcov takes every point and projected by PROJ,
lands at its ENU x, y, at sea level and at an origin 2,500 m up."""

import numpy as np
import pytest

rasterio = pytest.importorskip("rasterio")

from rasterio.warp import transform  # noqa: E402

from pdcov.core.geodesy import Origin, enu_to_geodetic  # noqa: E402
from pdcov.report.gis import local_crs_wkt  # noqa: E402


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
