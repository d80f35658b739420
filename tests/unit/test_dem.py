"""The DEM reader (core/dem.py) and the mission's ``terrain`` section: heights at geodetic
points by hand on small rasters, the same tilted plane from a geographic and a UTM raster,
SRTM .hgt, the ellipsoid datum, windowed reads, the grid's corner heights in ENU with the
earth's curvature, and every bad input refused in one line naming the file."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
import yaml

from pdcov.commands.mission_file import load_mission_warned
from pdcov.config.load import mission_from_dict
from pdcov.core.dem import Dem, terrain_surface
from pdcov.core.domain import GridGeometry
from pdcov.core.geodesy import Origin, geodetic_to_enu
from pdcov.errors import ConfigError, InputFileError
from pdcov.flight.ground_altitude import GroundAltitude
from pdcov.service.settings import mission_hash
from tests.support.evaluate_inputs import ORIGIN as EVAL_ORIGIN
from tests.support.evaluate_inputs import known_flight, mission_doc, run, write_config
from tests.support.mavlink_fixtures import samples_from_flight, write_tlog

rasterio = pytest.importorskip("rasterio")
from rasterio.transform import from_origin  # noqa: E402
from rasterio.warp import transform as warp_transform  # noqa: E402

LAT0, LON0, H0 = 46.5, 7.5, 1000.0
ORIGIN = Origin(LAT0, LON0, H0)
UTM32N = "EPSG:32632"
# WGS84 radii of curvature at LAT0 (m): prime vertical N (east-west), meridian M.
_A, _F = 6378137.0, 1 / 298.257223563
_E2 = _F * (2 - _F)
_S2 = math.sin(math.radians(LAT0)) ** 2
N_M = _A / math.sqrt(1 - _E2 * _S2)
M_M = _A * (1 - _E2) / (1 - _E2 * _S2) ** 1.5


def drop_m(x: np.ndarray, y: np.ndarray, h_m: float = H0) -> np.ndarray:
    """The earth's curvature drop (m) of a point x east, y north of the origin at the
    origin's height: (x^2 / (N + h) + y^2 / (M + h)) / 2 (Euler's normal-section radii)."""
    return 0.5 * (x * x / (N_M + h_m) + y * y / (M_M + h_m))


def write_tif(path, heights, transform, crs="EPSG:4326", nodata=None, units=None,
              dtype="float64", scale=None, offset=None):
    """A one-band GeoTIFF of ``heights`` (row 0 at the top)."""
    heights = np.asarray(heights)
    with rasterio.open(path, "w", driver="GTiff", height=heights.shape[0],
                       width=heights.shape[1], count=1, dtype=dtype, crs=crs,
                       transform=transform, nodata=nodata) as dst:
        dst.write(heights.astype(dtype), 1)
        if units is not None:
            dst.units = (units,)
        if scale is not None:
            dst.scales, dst.offsets = (scale,), (offset,)
    return path


def geo_tif(path, heights, west_deg, north_deg, px_deg, **kw):
    return write_tif(path, heights, from_origin(west_deg, north_deg, px_deg, px_deg), **kw)


def flat_around(path, h_m=H0, half_deg=0.01, px_deg=0.001, lat_deg=LAT0, lon_deg=LON0,
                **kw):
    """A constant DEM over the square +-half_deg about (lat_deg, lon_deg)."""
    n = round(2 * half_deg / px_deg)
    return geo_tif(path, np.full((n, n), h_m), lon_deg - half_deg, lat_deg + half_deg,
                   px_deg, **kw)


def terrain_doc(dem, ground_alt_msl_m=None, **terrain):
    """The evaluate tests' mission moved to (LAT0, LON0): a 200 m square of 10 m cells
    about the origin, the DEM given."""
    doc = mission_doc(terrain={"dem": str(dem), **terrain})
    doc["origin"] = {"lat_deg": LAT0, "lon_deg": LON0, "ground_alt_msl_m": ground_alt_msl_m}
    doc["domain"] = {"polygon_enu_m": [[-100, -100], [100, -100], [100, 100], [-100, 100]],
                     "cell_size_m": 10.0}
    return doc


def refusal(tmp_path, doc) -> str:
    with pytest.raises(ConfigError) as exc:
        mission_from_dict(doc, source="m.yaml", base_dir=tmp_path)
    message = str(exc.value)
    assert "\n" not in message and message.startswith("m.yaml: terrain.")
    return message


# --- heights at geodetic points -----------------------------------------------------------

def test_pixel_centres_bilinear_by_hand(tmp_path):
    # 3 x 3 pixels of 0.1 deg from (47 N, 7 E): pixel (row r, col c) has its centre at
    # lat 46.95 - 0.1 r, lon 7.05 + 0.1 c and the height 3 r + c.
    dem = Dem.open(geo_tif(tmp_path / "d.tif", np.arange(9.0).reshape(3, 3), 7.0, 47.0, 0.1))
    lat = np.array([46.85, 46.85, 46.90, 46.99, 46.75, 46.70, 46.95, 47.01])
    lon = np.array([7.15, 7.20, 7.10, 7.01, 7.20, 7.30, 6.99, 7.05])
    want = [4.0, 4.5, 2.0,  # a centre; halfway east; amid four centres (0+1+3+4)/4
            0.0,  # the outer half pixel: the edge pixel's height
            7.5,  # between the bottom centres 7 and 8
            8.0,  # the raster's SE corner
            np.nan, np.nan]  # west of it, north of it
    np.testing.assert_allclose(dem.height_msl_m(lat, lon), want, atol=1e-9)
    assert dem.height_msl_m(46.85, 7.15).shape == ()


def test_nodata_is_nan_next_to_it_only(tmp_path):
    h = np.arange(9.0).reshape(3, 3)
    h[2, 2] = -9999.0
    dem = Dem.open(geo_tif(tmp_path / "d.tif", h, 7.0, 47.0, 0.1, nodata=-9999.0))
    got = dem.height_msl_m(np.array([46.75, 46.80, 46.90]), np.array([7.25, 7.20, 7.10]))
    assert math.isnan(got[0]) and math.isnan(got[1])  # beside / amid the hole's centre
    assert got[2] == pytest.approx(2.0)


def test_scale_and_offset_are_applied(tmp_path):
    raw = np.full((2, 2), 1234)  # int16 decimetres above 500 m
    dem = Dem.open(geo_tif(tmp_path / "d.tif", raw, 7.0, 47.0, 0.1, dtype="int16",
                           scale=0.1, offset=500.0))
    assert dem.height_msl_m(46.9, 7.1) == pytest.approx(623.4)


def test_srtm_hgt_gives_its_corner_and_reads_a_window(tmp_path):
    # N46E007.hgt: 1201 x 1201 big-endian int16 samples, row 0 at 47 N, column 0 at 7 E,
    # 1/1200 deg apart (the samples are the pixel centres). Height 500 + row.
    rows = np.arange(1201, dtype=">i2")[:, None]
    h = np.broadcast_to(500 + rows, (1201, 1201)).astype(">i2")
    h[600, 600] = -32768  # a void (SRTM's nodata) at 46.5 N, 7.5 E
    path = tmp_path / "N46E007.hgt"
    h.tofile(path)
    whole = Dem.open(path)
    got = whole.height_msl_m(np.array([47.0, 46.0, 46.25, 46.25 - 1 / 2400, 46.5]),
                             np.array([7.0, 8.0, 7.3, 7.3, 7.5]))
    np.testing.assert_allclose(got[:4], [500.0, 1700.0, 1400.0, 1400.5], atol=1e-9)
    assert math.isnan(got[4])
    # A window about a small area holds only what it needs, with the same heights.
    part = Dem.open(path, area_lonlat_deg=(7.29, 46.24, 7.31, 46.26), margin_m=100.0)
    assert part.heights_msl_m.size < 100 * 100
    lat, lon = np.linspace(46.24, 46.26, 7), np.linspace(7.29, 7.31, 7)
    np.testing.assert_allclose(part.height_msl_m(lat, lon), whole.height_msl_m(lat, lon),
                               atol=1e-9)
    assert np.isnan(part.height_msl_m(46.5, 7.5 + 0.01))  # beyond the window read


def test_ellipsoid_heights_become_msl(tmp_path):
    path = flat_around(tmp_path / "d.tif", h_m=1050.0)
    dem = Dem.open(path, vertical_datum="ellipsoid", geoid_height_m=50.0)
    assert dem.height_msl_m(LAT0, LON0) == pytest.approx(1000.0)  # H = h - N
    with pytest.raises(InputFileError, match="geoid_height_m is needed with the ellipsoid"):
        Dem.open(path, vertical_datum="ellipsoid")
    m = mission_from_dict(terrain_doc(path, vertical_datum="ellipsoid", geoid_height_m=50.0),
                          source="m.yaml", base_dir=tmp_path)
    assert m.ground_alt_msl_m == pytest.approx(1000.0)


# --- corner heights in ENU -----------------------------------------------------------------

def _plane_msl_m(lat_deg, lon_deg):
    """A tilted plane in the origin's east/north: H = 1000 + 0.1 x - 0.05 y (m MSL)."""
    r = geodetic_to_enu(lat_deg, lon_deg, H0, ORIGIN)
    return H0 + 0.1 * r[..., 0] - 0.05 * r[..., 1]


def test_geographic_and_utm_dems_of_one_plane_agree(tmp_path):
    # Geographic: 1e-4 deg pixels; UTM 32N: 10 m pixels; both sampled at pixel centres.
    n = 40
    west, north = LON0 - 0.002, LAT0 + 0.002
    lat_c = north - 1e-4 * (np.arange(n) + 0.5)
    lon_c = west + 1e-4 * (np.arange(n) + 0.5)
    geo = geo_tif(tmp_path / "geo.tif", _plane_msl_m(*np.meshgrid(lat_c, lon_c,
                                                                  indexing="ij")),
                  west, north, 1e-4)
    (e0,), (n0,) = warp_transform("EPSG:4326", UTM32N, [LON0], [LAT0])
    e_left, n_top = round(e0) - 200.0, round(n0) + 200.0
    ee, nn = np.meshgrid(e_left + 10 * (np.arange(n) + 0.5), n_top - 10 * (np.arange(n) + 0.5))
    lon_u, lat_u = warp_transform(UTM32N, "EPSG:4326", ee.ravel(), nn.ravel())
    utm = write_tif(tmp_path / "utm.tif",
                    _plane_msl_m(np.reshape(lat_u, ee.shape), np.reshape(lon_u, ee.shape)),
                    from_origin(e_left, n_top, 10.0, 10.0), crs=UTM32N)
    g = GridGeometry(-100.0, -100.0, 10.0, 20, 20)
    z_geo = terrain_surface(Dem.open(geo), g, ORIGIN).z_corner_m
    z_utm = terrain_surface(Dem.open(utm), g, ORIGIN).z_corner_m
    np.testing.assert_allclose(z_utm, z_geo, atol=1e-6)
    # By hand: the plane's rise minus the curvature drop (3.1 mm at 200 m).
    x, y = np.meshgrid(-100.0 + 10 * np.arange(21), -100.0 + 10 * np.arange(21))
    np.testing.assert_allclose(z_geo, 0.1 * x - 0.05 * y - drop_m(x, y), atol=1e-6)


def test_flat_dem_at_the_ground_altitude_gives_the_curvature_drop_only(tmp_path):
    m = mission_from_dict(terrain_doc(flat_around(tmp_path / "d.tif")), source="m.yaml",
                          base_dir=tmp_path)
    assert (m.ground_alt_msl_m, m.ground_alt_how) == (H0, "the DEM at the origin")
    z = m.terrain.z_corner_m
    assert z.shape == (21, 21) and m.new_mission_grid().terrain is m.terrain
    assert abs(z[10, 10]) < 1e-9  # the corner at the origin
    x, y = np.meshgrid(-100.0 + 10 * np.arange(21), -100.0 + 10 * np.arange(21))
    np.testing.assert_allclose(z, -drop_m(x, y), atol=1e-8)  # 1.57 mm at the corners
    # Without a terrain section the ground is today's plane z = 0.
    flat = mission_from_dict({**terrain_doc("-"), "terrain": None}, source="m.yaml",
                             base_dir=tmp_path)
    assert flat.terrain is None and flat.dem is None and flat.new_mission_grid().terrain is None


def test_corners_outside_the_free_cells_may_lack_heights(tmp_path):
    # Nodata from 0.0004 deg (31 m) east of the origin on; an obstacle covers the domain
    # east of x = 10 m, so no free cell needs those heights: its corners take the nearest.
    path = flat_around(tmp_path / "d.tif", half_deg=0.01, px_deg=0.0002)
    with rasterio.open(path, "r+") as ds:
        h = ds.read(1)
        h[:, 52:] = -1.0
        ds.nodata = -1.0
        ds.write(h, 1)
    doc = terrain_doc(path)
    doc["domain"]["obstacles_enu_m"] = [[[10, -110], [110, -110], [110, 110], [10, 110]]]
    m = mission_from_dict(doc, source="m.yaml", base_dir=tmp_path)
    z = m.terrain.z_corner_m
    assert np.isnan(m.dem.height_msl_m(LAT0, LON0 + 0.0006))  # 46 m east: none there
    # Corners x >= 40 m had none; they took the nearest corner's 1000 m MSL, which is
    # then placed in ENU as every other (the curvature drop of a flat DEM).
    x, y = np.meshgrid(-100.0 + 10 * np.arange(21), -100.0 + 10 * np.arange(21))
    np.testing.assert_allclose(z, -drop_m(x, y), atol=1e-8)


# --- bad input: one line naming the file ----------------------------------------------------

def test_not_a_raster(tmp_path):
    (tmp_path / "dem.tif").write_text("elevation: high\n")
    msg = refusal(tmp_path, terrain_doc("dem.tif"))
    assert "dem.tif: not a raster rasterio can read" in msg


def test_no_crs(tmp_path):
    path = write_tif(tmp_path / "dem.tif", np.full((3, 3), H0), from_origin(0, 3, 1, 1),
                     crs=None)
    assert "dem.tif: the raster has no CRS" in refusal(tmp_path, terrain_doc(path))


def test_partial_cover_says_how_much_and_where(tmp_path):
    # The DEM's east edge 0.0001 deg (7.7 m) east of the origin: the domain's cells east of
    # x = 0 (10 of its 20 columns) miss a corner.
    path = geo_tif(tmp_path / "dem.tif", np.full((20, 10), H0), LON0 - 0.0099, LAT0 + 0.01,
                   0.001)
    msg = refusal(tmp_path, terrain_doc(path))
    assert "dem.tif: the DEM covers only 50.0 % of the domain: 50.0 % (20,000 m^2)" in msg
    assert "on its east side (ENU x 5..95 m" in msg


def test_dem_kilometres_away(tmp_path):
    path = flat_around(tmp_path / "dem.tif", lat_deg=LAT0 + 0.05)  # 5.6 km north
    msg = refusal(tmp_path, terrain_doc(path, ground_alt_msl_m=H0))
    # 0.04 deg of latitude (4.45 km) from its south edge to the origin, less 100 m.
    assert re.search(r"does not cover the domain at all: .* 4\.3 km to the north of it", msg)


def test_dem_kilometres_away_without_a_ground_altitude_is_said_first(tmp_path):
    # No origin.ground_alt_msl_m: the DEM's height at the origin is wanted first, but a DEM
    # missing the whole domain is a wrong DEM, not a missing altitude (issue 39).
    path = flat_around(tmp_path / "dem.tif", lat_deg=LAT0 + 0.05)  # 5.6 km north
    msg = refusal(tmp_path, terrain_doc(path))
    assert re.search(r"does not cover the domain at all: .* 4\.3 km to the north of it", msg)
    assert "ground_alt_msl_m" not in msg


def test_nodata_holes_under_the_domain(tmp_path):
    path = flat_around(tmp_path / "dem.tif", px_deg=0.0002)
    with rasterio.open(path, "r+") as ds:
        h = ds.read(1)
        h[50, 50] = -1.0  # the pixel south-east of the origin
        ds.nodata = -1.0
        ds.write(h, 1)
    msg = refusal(tmp_path, terrain_doc(path, ground_alt_msl_m=H0))
    assert re.search(r"dem.tif: nodata under the domain: \d+ of its 400 free cells", msg)
    assert "fill the holes" in msg


@pytest.mark.parametrize("units", ["ft", "US survey foot"])
def test_heights_in_feet(tmp_path, units):
    path = flat_around(tmp_path / "dem.tif", h_m=3280.0, units=units)
    msg = refusal(tmp_path, terrain_doc(path))
    assert f"dem.tif: heights are in feet (band units {units!r})" in msg and "0.3048" in msg


@pytest.mark.parametrize("h_m", [-9999.0, 9500.0])
def test_absurd_heights(tmp_path, h_m):
    msg = refusal(tmp_path, terrain_doc(flat_around(tmp_path / "dem.tif", h_m=h_m)))
    assert f"heights {h_m:g} to {h_m:g} m MSL, outside -500..9000 m" in msg


def test_origin_off_the_dem_without_a_ground_altitude(tmp_path):
    doc = terrain_doc(flat_around(tmp_path / "dem.tif"))
    doc["domain"]["polygon_enu_m"] = [[400, 400], [600, 400], [600, 600], [400, 600]]
    doc["origin"]["lat_deg"] = LAT0 - 0.013  # 1.4 km south: off the DEM, the domain on it
    msg = refusal(tmp_path, doc)
    assert "no height at the origin" in msg and "set origin.ground_alt_msl_m" in msg


def test_configured_ground_altitude_far_from_the_dem_warns(tmp_path):
    path = flat_around(tmp_path / "dem.tif", h_m=1030.0)
    m = mission_from_dict(terrain_doc(path, ground_alt_msl_m=H0), source="m.yaml",
                          base_dir=tmp_path)
    (w,) = m.warnings
    assert w.startswith("m.yaml: origin.ground_alt_msl_m 1000.0 m MSL differs from the DEM's "
                        "1030.0 m there (dem.tif) by -30.0 m, more than "
                        "terrain.check_margin_m = 10 m")
    assert m.ground_alt_how == "configured"
    np.testing.assert_allclose(m.terrain.z_corner_m[10, 10], 30.0, atol=1e-6)
    calm = mission_from_dict(terrain_doc(path, ground_alt_msl_m=H0, check_margin_m=50),
                             source="m.yaml", base_dir=tmp_path)
    assert calm.warnings == ()


@pytest.mark.parametrize(("terrain", "words"), [
    ({"dme": "d.tif"}, "terrain.dme: unknown key; did you mean 'dem'?"),
    ({"dem": "d.tif", "vertical_datum": "wgs84"}, "expected 'msl' or 'ellipsoid'"),
    ({"dem": "d.tif", "vertical_datum": "ellipsoid"}, "terrain.geoid_height_m: missing"),
    ({"dem": "d.tif", "geoid_height_m": 48.0}, "only used with vertical_datum: ellipsoid"),
    ({"dem": "missing.tif"}, "terrain.dem: file not found"),
    ({"dem": "d.tif", "check_margin_m": 0}, "terrain.check_margin_m: expected a positive"),
])
def test_terrain_section_is_checked(tmp_path, terrain, words):
    flat_around(tmp_path / "d.tif")
    doc = terrain_doc("d.tif")
    doc["terrain"] = terrain
    assert words in refusal(tmp_path, doc)


def test_the_live_ground_altitude_says_it_came_from_the_dem():
    ground = GroundAltitude(H0, 5.0, "the DEM at the origin")
    assert ground.ground_alt(-math.inf) == (H0, "the DEM at the origin")


def test_commands_show_the_mission_warnings(tmp_path, capsys):
    flat_around(tmp_path / "dem.tif", h_m=1030.0)
    path = tmp_path / "mission.yaml"
    path.write_text(yaml.safe_dump(terrain_doc("dem.tif", ground_alt_msl_m=H0)))
    load_mission_warned(path, "plan")
    err = capsys.readouterr().err
    assert err.startswith(f"pdcov plan: WARNING: {path}: origin.ground_alt_msl_m 1000.0 m MSL "
                          "differs from the DEM's 1030.0 m") and err.count("\n") == 1


def test_a_checkpoint_belongs_to_its_terrain(tmp_path):
    flat_around(tmp_path / "a.tif")
    flat_around(tmp_path / "b.tif", h_m=H0 + 5.0)
    a, b = (mission_from_dict(terrain_doc(f, ground_alt_msl_m=H0), source="m.yaml",
                              base_dir=tmp_path) for f in ("a.tif", "b.tif"))
    flat = mission_from_dict({**terrain_doc("-", ground_alt_msl_m=H0), "terrain": None},
                             source="m.yaml", base_dir=tmp_path)
    hashes = {mission_hash(m, m.new_mission_grid()) for m in (a, b, flat)}
    assert len(hashes) == 3


def test_evaluate_says_where_the_ground_came_from_and_warns(tmp_path, capsys):
    # The known flight of the evaluate tests, over a flat DEM around its origin.
    o = EVAL_ORIGIN
    tlog = write_tlog(tmp_path / "flight.tlog", samples_from_flight(known_flight()))
    flat_around(tmp_path / "dem.tif", h_m=o.ground_alt_msl_m, lat_deg=o.lat_deg,
                lon_deg=o.lon_deg)
    doc = mission_doc(terrain={"dem": "dem.tif"})
    doc["origin"]["ground_alt_msl_m"] = None
    config = write_config(tmp_path, doc)
    assert run("evaluate", "--config", str(config), "--log", str(tlog), "--out",
               str(tmp_path / "a"), "--no-progress") == 0
    assert f"ground {o.ground_alt_msl_m:.2f} m MSL (the DEM at the origin)" in (
        capsys.readouterr().out)
    doc["origin"]["ground_alt_msl_m"] = o.ground_alt_msl_m - 5.0
    doc["terrain"]["check_margin_m"] = 2.0
    write_config(tmp_path, doc)
    assert run("evaluate", "--config", str(config), "--log", str(tlog), "--out",
               str(tmp_path / "b"), "--no-progress") == 0
    out, err = capsys.readouterr()
    assert "pdcov evaluate: WARNING: " in err and "by -5.0 m" in err
    assert "(configured)" in out and "WARNING: " in out
    (w,) = json.loads((tmp_path / "b" / "metrics.json").read_text())["warnings"]
    assert "differs from the DEM's 5.0 m there (dem.tif) by -5.0 m" in w


def test_configured_home_altitude_beyond_max_home_offset_is_refused_unless_raised(tmp_path):
    path = flat_around(tmp_path / "dem.tif", h_m=H0 + 188.0)
    with pytest.raises(ConfigError) as exc:
        mission_from_dict(terrain_doc(path, ground_alt_msl_m=H0), source="m.yaml",
                          base_dir=tmp_path)
    assert str(exc.value).startswith(
        "m.yaml: origin.ground_alt_msl_m: 1000.0 m MSL is -188.0 m from the DEM's 1188.0 m "
        "there (dem.tif), more than terrain.max_home_offset_m = 30 m")
    m = mission_from_dict(terrain_doc(path, ground_alt_msl_m=H0, max_home_offset_m=200),
                          source="m.yaml", base_dir=tmp_path)
    assert "differs from the DEM's 1188.0 m" in m.warnings[0]  # raised: taken, still warned
