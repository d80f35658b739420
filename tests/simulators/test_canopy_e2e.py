"""End to end under trees and roofs (issue 38): the hill and ridge of
tests/support/terrain_scene.py with a stand of trees on the hill's flank and a house, as a
mission config would give them (a DSM GeoTIFF in UTM 32N and an ESA WorldCover-coded land
cover in WGS84): ``pdcov-sitl fly`` -> ``pdcov serve`` over UDP -> the daemon's snapshot,
tiles and checkpoint equal ``pdcov evaluate`` of the simulator's tlog cell for cell; the
trees limit the cells under them (CANOPY, P_D below the open ground's) and nothing under
the roof is seen (BUILDING, P_D 0)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("jsbsim")
rasterio = pytest.importorskip("rasterio")

from rasterio.transform import from_origin  # noqa: E402
from scipy.ndimage import binary_dilation, binary_erosion  # noqa: E402

from pdcov.core.geodesy import enu_to_geodetic, geodetic_to_enu  # noqa: E402
from pdcov.core.limiting import LimitingFactor  # noqa: E402
from tests.support import terrain_scene as scene  # noqa: E402
from tests.support.serve_harness import fly_udp, live_equals_offline, offline  # noqa: E402
from tests.support.valley import write_enu_geotiff  # noqa: E402

TREES_ENU_M = (2.0, 22.0, 22.0, 38.0)  # x_min, x_max, y_min, y_max: 9 m trees
TREE_M = 9.0
HOUSE_ENU_M = (28.0, 36.0, 4.0, 12.0)  # a 6 m house
HOUSE_M = 6.0
LOOKING_EAST = {"type": "fixed", "roll_deg": 0, "pitch_deg": -60, "yaw_deg": 0}
SURVEY_XY_M = [(0.0, 8.0), (40.0, 8.0), (40.0, 30.0), (0.0, 30.0)]
SURVEY_Z_M = 35.0


def inside(x: np.ndarray, y: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
    return (x >= box[0]) & (x < box[1]) & (y >= box[2]) & (y < box[3])


def objects_m(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Height (m) of what stands at ENU x, y: the trees and the house."""
    return np.where(inside(x, y, TREES_ENU_M), TREE_M,
                    np.where(inside(x, y, HOUSE_ENU_M), HOUSE_M, 0.0))


def write_landcover(path: Path) -> Path:
    """ESA WorldCover codes in WGS84 (about 0.5 m pixels): 10 (tree cover) under the trees,
    50 (built-up) under the house, 30 (grassland) elsewhere."""
    o = scene.origin()
    lo = enu_to_geodetic(np.array([-scene.EXTENT_M, -scene.EXTENT_M, 0.0]), o)
    hi = enu_to_geodetic(np.array([scene.DOMAIN_M + scene.EXTENT_M,
                                   scene.DOMAIN_M + scene.EXTENT_M, 0.0]), o)
    step = 5e-6  # deg
    n_cols = math.ceil((hi[1] - lo[1]) / step)
    n_rows = math.ceil((hi[0] - lo[0]) / step)
    lon = lo[1] + step * (np.arange(n_cols) + 0.5)
    lat = hi[0] - step * (np.arange(n_rows) + 0.5)
    LON, LAT = np.meshgrid(lon, lat)
    enu = geodetic_to_enu(LAT, LON, np.full(LAT.shape, o.ground_alt_msl_m), o)
    x, y = enu[..., 0], enu[..., 1]
    codes = np.where(inside(x, y, TREES_ENU_M), 10,
                     np.where(inside(x, y, HOUSE_ENU_M), 50, 30)).astype(np.uint8)
    with rasterio.open(path, "w", driver="GTiff", width=n_cols, height=n_rows, count=1,
                       dtype="uint8", crs="EPSG:4326", nodata=0,
                       transform=from_origin(lo[1], hi[0], step, step)) as dst:
        dst.write(codes, 1)
    return path


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> dict:
    tmp = tmp_path_factory.mktemp("canopy")
    o = scene.origin()
    dem = scene.write_dem(tmp / "dem.tif")
    box = (-scene.EXTENT_M, -scene.EXTENT_M, scene.DOMAIN_M + scene.EXTENT_M,
           scene.DOMAIN_M + scene.EXTENT_M)
    dsm = write_enu_geotiff(tmp / "dsm.tif", lambda x, y: scene.height_enu_m(x, y)
                            + objects_m(x, y), o.lat_deg, o.lon_deg, o.ground_alt_msl_m,
                            box, 1.0)
    land = write_landcover(tmp / "landcover.tif")
    doc = scene.terrain_mission(dem, vehicle_id="sim1", mount=LOOKING_EAST)
    doc["terrain"].update(surface=str(dsm), landcover=str(land), search_under_roofs=True)
    plan = scene.write_survey(tmp / "survey.waypoints", SURVEY_XY_M, SURVEY_Z_M)
    out = fly_udp(tmp, doc, plan)
    out["sim"] = offline(out["cfg"], tmp / "fly" / "flight.tlog", tmp / "off-sim")
    out["metrics"] = yaml.safe_load((tmp / "off-sim" / "metrics.json").read_text())
    return out


def test_live_equals_offline_under_trees_and_roofs(flight):
    live_equals_offline(flight)


def test_trees_limit_the_cells_under_them_and_roofs_hide_everything(flight):
    ref = flight["sim"]
    limiting, mask = ref["limiting"], ref["mask"]
    pd = -np.expm1(ref["log_miss_d"].astype(np.float64))
    y, x = np.mgrid[0:mask.shape[0], 0:mask.shape[1]] + 0.5  # 1 m cells from (0, 0)
    trees, house = inside(x, y, TREES_ENU_M), inside(x, y, HOUSE_ENU_M)
    counts = flight["metrics"]["limiting_cells"]
    print(f"limiting factors of the {int(mask.sum())} cells: {counts}")
    # The rasters' pixels (UTM, WGS84) do not line up with the cells: an edge may move by
    # a cell.
    near_trees, near_house = (binary_dilation(m, np.ones((3, 3), bool)) for m in (trees, house))
    canopy = limiting == LimitingFactor.CANOPY
    assert counts["canopy"] == canopy.sum() > 100 and (canopy <= near_trees).all()
    roof = limiting == LimitingFactor.BUILDING
    assert counts["building"] == roof.sum() > 20 and (roof <= near_house).all()
    assert not pd[roof].any() and not pd[binary_erosion(house)].any()
    # Per look, log(1 - P_D T) under the trees against log(1 - P_D) in the open.
    per_look = ref["log_miss_d"] / np.maximum(ref["n_obs"], 1)
    seen_open = (limiting == LimitingFactor.SEEN) & ~near_trees & ~near_house
    print(f"median log(1 - P_D) per look: under trees {np.median(per_look[canopy]):.3f}, "
          f"in the open {np.median(per_look[seen_open]):.3f}")
    assert np.median(per_look[canopy]) > 0.5 * np.median(per_look[seen_open])
