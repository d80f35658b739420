"""The grid's GeoTIFFs of a run (pd.tif, looks.tif, limiting.tif) and the P_D overlay in
Web Mercator (pd_rgba_3857.tif), read back by rasterio and by GDAL's gdalinfo (Debian's
gdal-bin, which .ci/run installs): the mission's UTM zone (EPSG:32618) with each pixel the
value of the grid cell under its centre, types, nodata, band descriptions and metadata, the
COG layout, the Web Mercator file's corners and its colours against pd_overlay.png
(test_geotiff_utm.py: the positions at other sites)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from pdcov import __version__
from pdcov.cli import main
from pdcov.core.domain import GridGeometry
from pdcov.core.geodesy import enu_to_geodetic
from pdcov.core.limiting import LimitingFactor
from pdcov.report.gis import local_crs_wkt
from tests.support.evaluate_inputs import (
    ORIGIN,
    expected_poses,
    known_flight,
    mission_doc,
    write_config,
    write_pose_csv,
)
from tests.support.utm_cells import pixel_cells

rasterio = pytest.importorskip("rasterio")
pytestmark = pytest.mark.skipif(shutil.which("gdalinfo") is None,
                                reason="needs GDAL's gdalinfo (apt-get install gdal-bin; "
                                       ".ci/run does)")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("geotiffs")
    config = write_config(folder, mission_doc())  # 40 x 40 cells about an obstacle
    poses = write_pose_csv(folder / "poses.csv", expected_poses(known_flight(), None))
    out = folder / "run"
    assert main(["evaluate", "--config", str(config), "--poses", str(poses), "--out",
                 str(out), "--no-progress"]) == 0
    return out


def gdalinfo(path: Path) -> dict:
    return json.loads(subprocess.run(["gdalinfo", "-json", str(path)], capture_output=True,
                                     text=True, check=True, timeout=60).stdout)


def grid(run: Path) -> tuple[dict[str, np.ndarray], GridGeometry]:
    with np.load(run / "grid.npz") as z:
        return ({k: z[k] for k in ("pd", "pfa", "n_obs", "limiting", "mask")},
                GridGeometry(float(z["x0_m"]), float(z["y0_m"]), float(z["cell_size_m"]),
                             *z["mask"].shape))


@pytest.mark.parametrize(("name", "bands", "gdal_type", "nodata"), [
    ("pd.tif", ("pd", "pfa"), "Float32", "NaN"),
    ("looks.tif", ("n_obs",), "Int32", -1),
    ("limiting.tif", ("limiting",), "Byte", 255)])
def test_grid_bands_in_their_types_with_nodata_outside_the_free_cells(
        run, name, bands, gdal_type, nodata):
    g, geometry = grid(run)
    frames = json.loads((run / "metrics.json").read_text())["frames"]
    with rasterio.open(run / name) as src:
        assert src.descriptions == bands and src.crs.to_epsg() == 32618  # ORIGIN: 76.33 W
        assert src.res == (geometry.cell_size_m, geometry.cell_size_m)
        cells = pixel_cells(src, geometry, ORIGIN)
        assert set(src.dtypes) == {gdal_type.lower().replace("byte", "uint8")}
        tags = src.tags()
        assert tags["PDCOV_VERSION"] == __version__ and tags["VEHICLE"] == "uav1"
        assert tags["FRAMES"] == str(frames) and tags["TITLE"] == "uav1: poses.csv"
        assert float(tags["ENU_ORIGIN_LON_DEG"]) == ORIGIN.lon_deg
        # Each pixel the value of the cell under its centre (away from cell edges), nodata
        # beyond the grid and on cells not free.
        free = g["mask"][cells.cell_row, cells.cell_col]
        on_free, off = cells.clear & free, ~cells.inside | (cells.clear & ~free)
        assert on_free.sum() > 0.9 * (cells.inside & free).sum()
        for i, band in enumerate(bands, start=1):
            back = src.read(i).ravel()
            assert src.tags(i)["LONG_NAME"] and src.units[i - 1] == src.tags(i)["UNITS"]
            np.testing.assert_array_equal(
                back[on_free], g[band][cells.cell_row, cells.cell_col][on_free].astype(
                    src.dtypes[0]))
            if nodata == "NaN":
                assert np.isnan(src.nodata) and np.isnan(back[off]).all()
            else:
                assert src.nodata == nodata and (back[off] == nodata).all()
    assert g["mask"].any() and not g["mask"].all()
    info = gdalinfo(run / name)
    assert info["stac"]["proj:epsg"] == 32618
    assert info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"] == "COG"
    assert info["metadata"][""]["PDCOV_VERSION"] == __version__
    for band, b in zip(bands, info["bands"], strict=True):
        assert b["type"] == gdal_type and b["description"] == band
        assert str(b["noDataValue"]) == str(nodata) if nodata == "NaN" \
            else b["noDataValue"] == nodata
        assert b["unit"] == b["metadata"][""]["UNITS"]


def test_limiting_tif_names_its_codes(run):
    codes = gdalinfo(run / "limiting.tif")["metadata"][""]["LIMITING_CODES"]
    table = dict(item.split("=") for item in codes.split(", "))
    assert table == {str(f.value): f.name.lower() for f in LimitingFactor}


def test_rgba_3857_lands_on_the_grid_with_the_overlays_colours(run):
    from PIL import Image
    from rasterio.warp import transform

    origin = ORIGIN
    with np.load(run / "grid.npz") as z:
        x0, y0, c = float(z["x0_m"]), float(z["y0_m"]), float(z["cell_size_m"])
        n_rows, n_cols = z["mask"].shape
    info = gdalinfo(run / "pd_rgba_3857.tif")
    assert info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"] == "COG"
    assert [b["colorInterpretation"] for b in info["bands"]] == [
        "Red", "Green", "Blue", "Alpha"]
    assert {b["type"] for b in info["bands"]} == {"Byte"}
    with rasterio.open(run / "pd_rgba_3857.tif") as src:
        assert src.crs.to_epsg() == 3857 and src.count == 4
        rgba, t, bounds = src.read(), src.transform, src.bounds
    px = abs(t.a)
    # The grid's corners (WGS84) in Web Mercator: the raster's bounds within a pixel.
    corners = enu_to_geodetic(np.array([[x0, y0, 0.0], [x0 + n_cols * c, y0, 0.0],
                                        [x0 + n_cols * c, y0 + n_rows * c, 0.0],
                                        [x0, y0 + n_rows * c, 0.0]]), origin)
    xs, ys = transform("EPSG:4326", "EPSG:3857", corners[:, 1], corners[:, 0])
    assert min(xs) == pytest.approx(bounds.left, abs=px)
    assert max(xs) == pytest.approx(bounds.right, abs=px)
    assert min(ys) == pytest.approx(bounds.bottom, abs=px)
    assert max(ys) == pytest.approx(bounds.top, abs=px)

    # Every pixel's centre back on the grid: the colour of pd_overlay.png's cell there.
    overlay = np.asarray(Image.open(run / "pd_overlay.png").convert("RGBA"))
    assert overlay.shape[:2] == (n_rows, n_cols)
    rows, cols = np.mgrid[0:rgba.shape[1], 0:rgba.shape[2]]
    mx, my = rasterio.transform.xy(t, rows.ravel(), cols.ravel())
    ex, ey = (np.asarray(v) for v in transform("EPSG:3857", local_crs_wkt(origin), mx, my))
    fc, fr = (ex - x0) / c, (ey - y0) / c  # grid column and row (rows growing north)
    inside = (fc >= 0) & (fc < n_cols) & (fr >= 0) & (fr < n_rows)
    pixels = rgba.reshape(4, -1).T
    assert (pixels[~inside, 3] == 0).all()
    clear = inside & (np.abs(fc - np.round(fc)) > 0.01) & (np.abs(fr - np.round(fr)) > 0.01)
    assert clear.sum() > 0.9 * inside.sum() > 0
    r, k = fr[clear].astype(int), fc[clear].astype(int)
    np.testing.assert_array_equal(pixels[clear], overlay[n_rows - 1 - r, k])
    assert len({tuple(p) for p in pixels[clear & (pixels[:, 3] > 0)]}) > 3  # P_D varies
