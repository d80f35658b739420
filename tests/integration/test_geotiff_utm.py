"""The grid's GeoTIFFs (report/gis.py ``write_geotiff``) land in the mission's UTM zone where
pdcov's own geodesy puts the cells: a 4 x 4-cell patch's value sampled at its centre, every
pixel the value of the cell under its centre (nearest neighbour: no value no cell had,
codes exact), the grid's corners within a pixel of the bounds, and the EPSG code as
rasterio and GDAL's gdalinfo read it; at a zone's edge (an origin just west and just east
of 6 E: zones 31 and 32, the grid straddling the edge), in the southern hemisphere
(EPSG:327xx) and in south-west Norway's zone exception."""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

from pdcov.core.domain import GridGeometry
from pdcov.core.geodesy import Origin
from pdcov.report.gis import LOOKS_NODATA, array_band, write_geotiff
from tests.support.utm_cells import enu_to_raster_xy, pixel_cells

rasterio = pytest.importorskip("rasterio")

PATCH = 4  # cells a side of a patch of one value in pd.tif
GEOMETRY = GridGeometry(-400.0, -300.0, 5.0, 120, 400)  # 2 x 0.6 km; 5.99 E: 5.98-6.01 E
SITES = [
    pytest.param((Origin(45.0, 5.99, 300.0), 32631), id="zone 31 at its edge"),
    pytest.param((Origin(45.0, 6.01, 300.0), 32632), id="zone 32 at its edge"),
    pytest.param((Origin(-33.9, 151.2, 40.0), 32756), id="southern"),
    pytest.param((Origin(60.4, 5.3, 1200.0), 32632), id="Norway"),
]


def cell_values() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """pd (one value per PATCH x PATCH patch), looks (a code per cell: its index) and the
    free cells (all but a block and a ring at the west edge)."""
    rows, cols = np.mgrid[0:GEOMETRY.n_rows, 0:GEOMETRY.n_cols]
    pd = ((rows // PATCH) * 1000 + cols // PATCH) / 1e5
    looks = rows * GEOMETRY.n_cols + cols
    free = ~((rows >= 40) & (rows < 60) & (cols >= 200) & (cols < 240)) & (cols > 0)
    return pd, looks, free


@pytest.fixture(scope="module", params=SITES)
def site(request, tmp_path_factory):
    origin, epsg = request.param
    folder = tmp_path_factory.mktemp("utm")
    pd, looks, free = cell_values()
    write_geotiff(folder / "pd.tif", {"pd": array_band(pd)}, GEOMETRY, origin,
                  array_band(free), tags={"TITLE": "t"})
    write_geotiff(folder / "looks.tif", {"n_obs": array_band(looks)}, GEOMETRY, origin,
                  array_band(free), dtype="int32", nodata=LOOKS_NODATA)
    return folder, origin, epsg


def test_the_crs_is_the_zones_epsg_by_rasterio_and_gdal(site):
    folder, origin, epsg = site
    for name in ("pd.tif", "looks.tif"):
        with rasterio.open(folder / name) as src:
            assert src.crs.to_epsg() == epsg and src.res == (5.0, 5.0)
            tags = src.tags()
        assert float(tags["ENU_ORIGIN_LAT_DEG"]) == origin.lat_deg
        assert float(tags["ENU_ORIGIN_LON_DEG"]) == origin.lon_deg
        assert float(tags["ENU_ORIGIN_ALT_MSL_M"]) == origin.ground_alt_msl_m
        assert tags["GRID_SW_ENU_M"] == "-400.0 -300.0" and tags["GRID_CELL_SIZE_M"] == "5.0"
        assert "east-north-up" in tags["ENU_PLANE"] and "+proj=tmerc" in tags["ENU_PLANE_PROJ"]
        if shutil.which("gdalinfo") is None:
            pytest.skip("needs GDAL's gdalinfo (apt-get install gdal-bin; .ci/run does)")
        info = json.loads(subprocess.run(["gdalinfo", "-json", str(folder / name)],
                                         capture_output=True, text=True, check=True,
                                         timeout=60).stdout)
        assert info["stac"]["proj:epsg"] == epsg
        assert info["coordinateSystem"]["wkt"].rstrip().endswith(f'ID["EPSG",{epsg}]]')
        assert info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"] == "COG"


def test_a_patchs_value_reads_back_at_its_centre(site):
    folder, origin, _ = site
    pd, _, free = cell_values()
    r, k = np.mgrid[0:GEOMETRY.n_rows:PATCH, 0:GEOMETRY.n_cols:PATCH]
    r, k = r.ravel(), k.ravel()
    keep = free[r, k] & free[r + PATCH - 1, k] & free[r, k + PATCH - 1]
    r, k = r[keep], k[keep]
    c = GEOMETRY.cell_size_m
    centres = np.c_[GEOMETRY.x0_m + (k + PATCH / 2) * c, GEOMETRY.y0_m + (r + PATCH / 2) * c]
    with rasterio.open(folder / "pd.tif") as src:
        x, y = enu_to_raster_xy(centres, origin, src.crs)
        got = np.array([v[0] for v in src.sample(zip(x, y, strict=True))])
    assert len(got) > 2000
    np.testing.assert_array_equal(got, pd[r, k].astype(np.float32))


def test_every_pixel_is_the_cell_under_its_centre(site):
    folder, origin, _ = site
    _, looks, free = cell_values()
    with rasterio.open(folder / "looks.tif") as src:
        assert src.nodata == LOOKS_NODATA and src.dtypes == ("int32",)
        band, cells = src.read(1).ravel(), pixel_cells(src, GEOMETRY, origin)
    on_free = free[cells.cell_row, cells.cell_col]
    clear = cells.clear & on_free
    assert clear.sum() > 0.95 * (cells.inside & on_free).sum()
    np.testing.assert_array_equal(band[clear], looks[cells.cell_row, cells.cell_col][clear])
    assert (band[~cells.inside] == LOOKS_NODATA).all()
    assert (band[cells.clear & ~on_free] == LOOKS_NODATA).all()
    # Turned by the meridian convergence (up to 2.1 degrees here), a few cells show twice
    # or not at all.
    assert len(np.unique(band[band >= 0])) > 0.99 * free.sum()


def test_the_grids_corners_lie_within_a_pixel_of_the_bounds(site):
    folder, origin, _ = site
    g = GEOMETRY
    x1, y1 = g.x0_m + g.n_cols * g.cell_size_m, g.y0_m + g.n_rows * g.cell_size_m
    with rasterio.open(folder / "pd.tif") as src:
        xs, ys = enu_to_raster_xy(np.array([[g.x0_m, g.y0_m], [x1, g.y0_m], [x1, y1],
                                            [g.x0_m, y1]]), origin, src.crs)
        b, px = src.bounds, src.res[0]
    assert b.left <= xs.min() < b.left + px and b.right - px < xs.max() <= b.right
    assert b.bottom <= ys.min() < b.bottom + px and b.top - px < ys.max() <= b.top
    assert b.left % px == 0 and b.top % px == 0  # on the zone's lattice of the cell size
