"""What stands on the ground, from the mission config: terrain.surface (a DSM over the DEM)
and terrain.landcover (class codes) make the terrain's GroundCover, cell by cell by hand on
real GeoTIFFs (DEM and DSM in UTM 32N, land cover in WGS84 degrees with nodata); the cells
under roofs are not free unless terrain.search_under_roofs; every refusal names the key."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pdcov.config.load import mission_from_dict
from pdcov.core.domain import Domain, GridGeometry, cell_polygons
from pdcov.core.geodesy import Origin, enu_to_geodetic, geodetic_to_enu
from pdcov.core.ground_cover import DEFAULT_EXTINCTION_PER_M, CoverKind
from pdcov.core.landcover import LandCover
from pdcov.errors import ConfigError, InputFileError
from tests.support.evaluate_inputs import mission_doc

rasterio = pytest.importorskip("rasterio")
from rasterio.transform import from_origin  # noqa: E402
from rasterio.warp import transform as warp_transform  # noqa: E402

LAT0, LON0, H0 = 46.5, 7.5, 1000.0
UTM32N = "EPSG:32632"
E0, N0 = (float(v[0]) for v in warp_transform("EPSG:4326", UTM32N, [LON0], [LAT0]))
OPEN, FOLIAGE, SOLID = CoverKind.OPEN, CoverKind.FOLIAGE, CoverKind.SOLID

# What stands on the 100 x 100 m domain of 10 m cells about the origin (cell (row i, col j)
# has its centre at x = -45 + 10 j, y = -45 + 10 i): ENU boxes (x0, x1, y0, y1), height
# above the ground (m) and the land-cover code there (0: the land cover's nodata). Their
# edges lie on cell edges, 5 m from every centre, farther than the rasters' pixels reach.
OBJECTS = [
    ((10, 30, 10, 30), 10.0, 50),    # a house: cells rows 6-7, cols 6-7
    ((-40, -10, -40, -20), 15.0, 10),  # trees: rows 1-2, cols 1-3
    ((-40, -30, 20, 30), 1.5, 30),   # a hedge, below min_object_height_m: row 7, col 1
    ((30, 40, -40, -30), 6.0, 30),   # a shed on grassland: row 1, col 8
    ((-40, -30, 0, 10), 12.0, 0),    # trees where the land cover has nodata: row 5, col 1
]
GRASS = 30


def plane(e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The ground (m MSL): a tilted plane in UTM, which bilinear interpolation keeps."""
    return H0 + 0.02 * (e - E0) + 0.01 * (n - N0)


def enu_of_utm(e: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lon, lat = warp_transform(UTM32N, "EPSG:4326", e.ravel(), n.ravel())
    r = geodetic_to_enu(np.asarray(lat), np.asarray(lon), H0, Origin(LAT0, LON0, H0))
    return r[:, 0].reshape(e.shape), r[:, 1].reshape(e.shape)


def in_box(x: np.ndarray, y: np.ndarray, box) -> np.ndarray:
    x0, x1, y0, y1 = box
    return (x >= x0) & (x < x1) & (y >= y0) & (y < y1)


def write(path, values, transform, crs, nodata=None, dtype="float64"):
    with rasterio.open(path, "w", driver="GTiff", height=values.shape[0],
                       width=values.shape[1], count=1, dtype=dtype, crs=crs,
                       transform=transform, nodata=nodata) as dst:
        dst.write(values.astype(dtype), 1)
    return path


def utm_centres(half_m: float, px_m: float) -> tuple[np.ndarray, np.ndarray]:
    n = round(2 * half_m / px_m)
    c = (np.arange(n) + 0.5) * px_m
    return np.meshgrid(E0 - half_m + c, N0 + half_m - c)


def write_dem(tmp_path, offset_m=0.0, px_m=10.0, hole_at=None):
    """The DEM: the plane, px_m pixels 400 m about the origin, offset_m higher; hole_at:
    an ENU point (x, y) whose pixel is nodata."""
    e, n = utm_centres(400.0, px_m)
    h = plane(e, n) + offset_m
    if hole_at is not None:
        x, y = enu_of_utm(e, n)
        h[np.unravel_index(np.argmin(np.hypot(x - hole_at[0], y - hole_at[1])), h.shape)] = \
            -9999.0
    return write(tmp_path / "dem.tif", h, from_origin(E0 - 400, N0 + 400, px_m, px_m),
                 UTM32N, nodata=-9999.0)


def write_dsm(tmp_path, hole=None, west_m=150.0, offset_m=0.0):
    """The DSM: 2 m pixels over the ground and OBJECTS, 150 m about the origin, offset_m
    higher; ``hole``: an ENU box of nodata; west_m: how far west of the origin the raster
    reaches."""
    e, n = utm_centres(150.0, 2.0)
    keep = round((150.0 - west_m) / 2.0)
    e, n = e[:, keep:], n[:, keep:]
    x, y = enu_of_utm(e, n)
    h = plane(e, n) + offset_m
    for box, height, _ in OBJECTS:
        h = np.where(in_box(x, y, box), h + height, h)
    if hole is not None:
        h[in_box(x, y, hole)] = -9999.0
    return write(tmp_path / "dsm.tif", h, from_origin(E0 - west_m, N0 + 150, 2, 2), UTM32N,
                 nodata=-9999.0)


def write_landcover(tmp_path, dtype="uint8", values=None):
    """WorldCover-like codes in EPSG:4326 (pixels of 4e-5 deg: 4.4 x 3.1 m), nodata 0."""
    px = 4e-5
    n_lat, n_lon = 80, 100
    lat = LAT0 + 0.0016 - (np.arange(n_lat) + 0.5) * px
    lon = LON0 - 0.002 + (np.arange(n_lon) + 0.5) * px
    LON, LAT = np.meshgrid(lon, lat)
    r = geodetic_to_enu(LAT.ravel(), LON.ravel(), H0, Origin(LAT0, LON0, H0))
    x, y = r[:, 0].reshape(LAT.shape), r[:, 1].reshape(LAT.shape)
    codes = np.full(LAT.shape, GRASS)
    for box, _, code in OBJECTS:
        codes[in_box(x, y, box)] = code
    if values is not None:
        codes = values(codes)
    return write(tmp_path / "landcover.tif", codes, from_origin(LON0 - 0.002, LAT0 + 0.0016,
                                                                px, px), "EPSG:4326",
                 nodata=0, dtype=dtype)


def doc(tmp_path, *, with_dsm=True, with_landcover=True, **terrain):
    """The mission over the scene: the DEM, DSM and land cover written to tmp_path (those
    asked for), the terrain keys given."""
    d = mission_doc(terrain={"dem": str(write_dem(tmp_path)),
                             **({"surface": str(write_dsm(tmp_path))} if with_dsm else {}),
                             **({"landcover": str(write_landcover(tmp_path))}
                                if with_landcover else {}), **terrain})
    d["origin"] = {"lat_deg": LAT0, "lon_deg": LON0}
    d["domain"] = {"polygon_enu_m": [[-50, -50], [50, -50], [50, 50], [-50, 50]],
                   "cell_size_m": 10.0}
    return d


def load(tmp_path, d):
    return mission_from_dict(d, source="m.yaml", base_dir=tmp_path)


def refusal(tmp_path, d) -> str:
    with pytest.raises(ConfigError) as exc:
        load(tmp_path, d)
    message = str(exc.value)
    assert "\n" not in message
    return message


def cells(value, *where) -> np.ndarray:
    """A 10 x 10 array, 0 but ``value`` at the (row, col) cells ``where``."""
    a = np.zeros((10, 10))
    for rc in where:
        a[rc] = value
    return a


HOUSE = [(6, 6), (6, 7), (7, 6), (7, 7)]
TREES = [(r, c) for r in (1, 2) for c in (1, 2, 3)]
SHED, HEDGE, UNCLASSED = (1, 8), (7, 1), (5, 1)


# --- heights and kinds per cell --------------------------------------------------------------

def test_heights_and_kinds_per_cell_with_the_worldcover_classes(tmp_path):
    mission = load(tmp_path, doc(tmp_path))
    cover = mission.cover
    assert cover is not None and mission.terrain is not None
    assert mission.terrain.cover is cover
    want_h = (cells(10.0, *HOUSE) + cells(15.0, *TREES) + cells(6.0, SHED)
              + cells(12.0, UNCLASSED))  # the hedge, 1.5 m, is below 2 m: open
    # The DSM's pixel (2 m) a centre falls in, over a sloping plane: within its slope's
    # rise over a pixel's half-diagonal.
    np.testing.assert_allclose(cover.height_m, want_h, atol=0.05)
    assert cover.height_m.dtype == np.float32
    want_kind = (cells(SOLID, *HOUSE) + cells(FOLIAGE, *TREES)
                 + cells(SOLID, SHED)        # grassland (30) raised: not listed, solid
                 + cells(SOLID, UNCLASSED))  # land cover nodata: solid, and said
    np.testing.assert_array_equal(cover.kind, want_kind)
    assert cover.kind[HEDGE] == OPEN
    assert cover.extinction_per_m == DEFAULT_EXTINCTION_PER_M == 0.08
    (warning,) = [w for w in mission.warnings if "terrain.landcover" in w]
    assert warning.startswith("m.yaml: terrain.landcover: ")
    assert "1 of the 12 free cells raised 2 m or more" in warning and "taken as solid" in warning


def test_without_landcover_everything_raised_is_solid(tmp_path):
    cover = load(tmp_path, doc(tmp_path, with_landcover=False)).cover
    assert cover is not None
    raised = HOUSE + TREES + [SHED, UNCLASSED]
    np.testing.assert_array_equal(cover.kind, cells(SOLID, *raised))
    assert cover.height_m[HEDGE] == 0


def test_custom_classes_replace_the_default(tmp_path):
    d = doc(tmp_path, landcover_classes={10: "solid", 50: "foliage", "30": "open"},
            min_object_height_m=1.0, canopy_extinction_per_m=0.05)
    cover = load(tmp_path, d).cover
    assert cover is not None
    np.testing.assert_array_equal(
        cover.kind, cells(FOLIAGE, *HOUSE) + cells(SOLID, *TREES) + cells(SOLID, UNCLASSED))
    # Open ground whatever stands there: the shed and the hedge (raised 1.5 >= 1 m) on 30.
    assert cover.height_m[SHED] == 0 and cover.height_m[HEDGE] == 0
    assert cover.extinction_per_m == 0.05


def test_a_lower_min_object_height_raises_the_hedge(tmp_path):
    cover = load(tmp_path, doc(tmp_path, with_landcover=False, min_object_height_m=1.0)).cover
    assert cover is not None
    assert cover.height_m[HEDGE] == pytest.approx(1.5, abs=0.05)
    assert cover.kind[HEDGE] == SOLID


def test_the_dem_datum_applies_to_the_dsm(tmp_path):
    # Both on the ellipsoid, 48.6 m above MSL: the same heights above the ground.
    d = doc(tmp_path, vertical_datum="ellipsoid", geoid_height_m=48.6)
    write_dem(tmp_path, offset_m=48.6)
    write_dsm(tmp_path, offset_m=48.6)
    mission = load(tmp_path, d)
    assert mission.ground_alt_msl_m == pytest.approx(H0)
    assert mission.cover is not None
    np.testing.assert_allclose(mission.cover.height_m[6, 6], 10.0, atol=0.05)


def test_a_dsm_below_the_dem_is_warned_of(tmp_path):
    d = doc(tmp_path)
    write_dsm(tmp_path, offset_m=-48.6)  # a DSM on another datum than the DEM
    mission = load(tmp_path, d)
    assert mission.cover is not None and not mission.cover.height_m.any()
    (warning,) = [w for w in mission.warnings if "terrain.surface" in w]
    assert warning.startswith("m.yaml: terrain.surface: ")
    assert "below the DEM" in warning and "vertical datum" in warning


def test_a_dem_hole_between_the_corners_takes_the_terrain_at_the_centre(tmp_path):
    # A 2 m DEM pixel of nodata at the house's cell (6, 6) centre: the corners, 7 m away,
    # have their heights; the centre's ground is the terrain's there.
    d = doc(tmp_path)
    write_dem(tmp_path, px_m=2.0, hole_at=(15.0, 15.0))
    mission = load(tmp_path, d)
    assert mission.cover is not None and mission.dem is not None
    assert math.isnan(mission.dem.height_msl_m(*_latlon(15.0, 15.0)))
    np.testing.assert_allclose(mission.cover.height_m[6, 6], 10.0, atol=0.05)


def _latlon(x: float, y: float) -> tuple[float, float]:
    lat, lon, _ = enu_to_geodetic(np.array([x, y, 0.0]), Origin(LAT0, LON0, H0))
    return float(lat), float(lon)


def test_a_float_landcover_of_whole_numbers_is_read_by_nearest_pixel(tmp_path):
    path = write_landcover(tmp_path, dtype="float32")
    land = LandCover.open(path, area_lonlat_deg=(LON0 - 1e-3, LAT0 - 1e-3, LON0 + 1e-3,
                                                 LAT0 + 1e-3))
    codes, has = land.codes_at(np.array([LAT0, 89.0]), np.array([LON0, LON0]))
    assert codes.dtype == np.int64 and codes.tolist() == [GRASS, 0]
    assert has.tolist() == [True, False]  # the origin; a point off the raster


def test_fraction_codes_are_refused_naming_the_key(tmp_path):
    d = doc(tmp_path)
    write_landcover(tmp_path, dtype="float32", values=lambda c: c + 0.25)
    message = refusal(tmp_path, d)
    assert message.startswith("m.yaml: terrain.landcover: ")
    assert "class codes, whole numbers" in message and "30.25" in message


def test_a_window_beyond_the_bound_is_refused_with_gdal_translate(tmp_path):
    path = write_landcover(tmp_path)
    with pytest.raises(InputFileError) as exc:
        LandCover.open(path, area_lonlat_deg=(LON0 - 1e-3, LAT0 - 1e-3, LON0 + 1e-3,
                                              LAT0 + 1e-3), max_pixels=100)
    message = str(exc.value)
    assert message.startswith(f"{path}: the window over the domain is ")
    assert "more than 100" in message and "gdal_translate -projwin" in message


# --- free cells ------------------------------------------------------------------------------

def test_roofs_are_not_free_by_default_and_free_with_search_under_roofs(tmp_path):
    mission = load(tmp_path, doc(tmp_path))
    g = mission.domain.grid_geometry(mission.cell_size_m)
    roofs = HOUSE + [SHED, UNCLASSED]
    np.testing.assert_array_equal(mission.domain.free_mask(g), cells(1, *roofs) == 0)
    grid = mission.new_grid(mission.first_camera)
    np.testing.assert_array_equal(grid.free.dense(), cells(1, *roofs) == 0)
    assert grid.free.n_free == 100 - len(roofs)
    # The roofs are obstacles (the house, the shed, the unclassed trees), the trees are not.
    assert len(mission.domain.obstacles) == 3

    searched = load(tmp_path, doc(tmp_path, search_under_roofs=True))
    assert searched.domain.free_mask(g).all() and not searched.domain.obstacles
    assert searched.cover is not None and searched.cover.roof.sum() == len(roofs)


def test_the_mission_payload_gives_watchers_the_same_free_cells(tmp_path):
    from pdcov.bus.grid_state import grid_hash
    from pdcov.bus.mission import decode_mission, encode_mission

    mission = load(tmp_path, doc(tmp_path))
    grid = mission.new_grid(mission.first_camera)
    ghash = grid_hash(grid.geometry, grid.free)
    payload = encode_mission(mission.vehicle_id, mission.origin(), mission.domain,
                             grid.geometry, ghash, ground_alt_known=True,
                             thresholds=mission.thresholds, target_pd=0.8)
    got = decode_mission(payload).domain()
    np.testing.assert_array_equal(got.free_mask(grid.geometry),
                                  mission.domain.free_mask(grid.geometry))


def test_a_domain_all_under_roofs_is_refused(tmp_path):
    d = doc(tmp_path, with_landcover=False)
    d["domain"]["polygon_enu_m"] = [[10, 10], [30, 10], [30, 30], [10, 30]]
    message = refusal(tmp_path, d)
    assert message.startswith("m.yaml: terrain.surface: every free cell of the domain is "
                              "under solid cover")
    assert "terrain.search_under_roofs: true" in message


def test_cell_polygons_without_holes_cover_exactly_the_cells():
    g = GridGeometry(-5.0, -5.0, 1.0, 10, 10)
    m = np.zeros(g.shape, dtype=bool)
    m[1:5, 1:5] = True
    m[2:4, 2:4] = False  # a courtyard
    m[6, 6] = m[7, 7] = True  # touching at a corner
    m[6:9, 1] = True
    m[8, 1:4] = True  # an L
    polys = cell_polygons(g, m)
    assert all(p.is_valid and not p.interiors for p in polys)
    domain = Domain.from_enu([[-5, -5], [5, -5], [5, 5], [-5, 5]],
                             [list(p.exterior.coords) for p in polys])
    np.testing.assert_array_equal(domain.free_mask(g), ~m)
    assert len(polys) == 4 + 2 + 1  # courtyard cut in 4, two corner cells, one L


# --- refusals --------------------------------------------------------------------------------

def test_dsm_nodata_under_a_free_cell_is_refused_naming_terrain_surface(tmp_path):
    d = doc(tmp_path)
    write_dsm(tmp_path, hole=(-50, -40, -50, -40))
    message = refusal(tmp_path, d)
    assert message.startswith("m.yaml: terrain.surface: ")
    assert "nodata under the domain: 1 of its 100 free cells" in message
    assert "have no height at their centre" in message


def test_a_dsm_missing_part_of_the_domain_says_how_much(tmp_path):
    d = doc(tmp_path)
    write_dsm(tmp_path, west_m=0.0)
    message = refusal(tmp_path, d)
    assert message.startswith("m.yaml: terrain.surface: ")
    assert "the DSM covers only" in message and "west side" in message


@pytest.mark.parametrize("looks", ["correlated", "viewpoint"])
def test_correlated_and_viewpoint_looks_are_refused_with_a_surface(tmp_path, looks):
    d = doc(tmp_path) | {"coverage": {"looks": looks}}
    message = refusal(tmp_path, d)
    assert message.startswith("m.yaml: terrain.surface: ")
    assert "independent looks only" in message and looks in message


@pytest.mark.parametrize("key, value", [
    ("landcover", "landcover.tif"), ("landcover_classes", {10: "foliage"}),
    ("canopy_extinction_per_m", 0.1), ("min_object_height_m", 3.0),
    ("search_under_roofs", True)])
def test_options_without_a_surface_are_refused_naming_the_key(tmp_path, key, value):
    d = doc(tmp_path, with_dsm=False, with_landcover=False, **{key: value})
    message = refusal(tmp_path, d)
    assert message.startswith(f"m.yaml: terrain.{key}: only used with terrain.surface")


@pytest.mark.parametrize("terrain, key, words", [
    ({"landcover_classes": {10: "trees"}}, "terrain.landcover_classes.10", "foliage, solid"),
    ({"landcover_classes": {"ten": "solid"}}, "terrain.landcover_classes", "integer"),
    ({"landcover_classes": [10, 50]}, "terrain.landcover_classes", "a mapping"),
    ({"canopy_extinction_per_m": -0.1}, "terrain.canopy_extinction_per_m", ">= 0"),
    ({"min_object_height_m": 0}, "terrain.min_object_height_m", "positive"),
    ({"search_under_roofs": "yes"}, "terrain.search_under_roofs", "true or false"),
    ({"surface": 3}, "terrain.surface", "path of a DSM"),
    ({"surface": "missing.tif"}, "terrain.surface", "file not found"),
])
def test_bad_values_are_refused_naming_the_key(tmp_path, terrain, key, words):
    message = refusal(tmp_path, doc(tmp_path, **terrain))
    assert message.startswith(f"m.yaml: {key}: ") and words in message


def test_landcover_classes_without_landcover_are_refused(tmp_path):
    message = refusal(tmp_path, doc(tmp_path, with_landcover=False,
                                    landcover_classes={10: "foliage"}))
    assert message.startswith("m.yaml: terrain.landcover_classes: only used with "
                              "terrain.landcover")


def test_a_misspelt_key_is_refused_with_the_right_one(tmp_path):
    d = doc(tmp_path)
    d["terrain"]["serch_under_roofs"] = True
    message = refusal(tmp_path, d)
    assert "terrain.serch_under_roofs: unknown key" in message
    assert "did you mean 'search_under_roofs'?" in message


def test_the_checkpoint_hash_follows_the_cover(tmp_path):
    from pdcov.service.settings import mission_hash

    def hashed(**terrain) -> str:
        mission = load(tmp_path, doc(tmp_path, **terrain))
        return mission_hash(mission, mission.new_grid(mission.first_camera))

    assert hashed() != hashed(canopy_extinction_per_m=0.05)
