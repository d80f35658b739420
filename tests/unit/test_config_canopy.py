"""What stands on the ground, from the mission config: terrain.surface (a DSM over the DEM)
and terrain.landcover (class codes) make the terrain's GroundCover, cell by cell by hand on
real GeoTIFFs (DEM and DSM in UTM 32N, land cover in WGS84 degrees with nodata); the cells
under roofs are not free unless terrain.search_under_roofs; every refusal names the key."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pdcov.core.domain import Domain, GridGeometry, cell_polygons
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.ground_cover import DEFAULT_EXTINCTION_PER_M, CoverKind
from pdcov.core.landcover import LandCover
from pdcov.errors import ConfigError, InputFileError

pytest.importorskip("rasterio")
from tests.support.canopy_config import (
    GRASS,
    H0,
    LAT0,
    LON0,
    doc,
    load,
    write_dem,
    write_dsm,
    write_landcover,
)

FOLIAGE, OPEN, SOLID = CoverKind.FOLIAGE, CoverKind.OPEN, CoverKind.SOLID


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
