"""R3, the per-pixel DEM ray caster (tests/support/terrain_reference.py): rays against surfaces
with answers by hand, the valley DEM read back through its CRS, flat ground equal to R1; then
the issue 21 check on the valley flight: flat pdcov misjudges it, pdcov with the DEM agrees."""

import math

import numpy as np
import pytest

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.pose import CameraPose
from tests.support.grid_agreement import R3_MIN_SHARE, R3_TOLERANCE_PD, terrain_agreement
from tests.support.references import ReferenceGrid, pixel_rays, r1_update
from tests.support.scenarios import scenarios
from tests.support.terrain_reference import Heightfield, TerrainReferenceGrid, r3_update
from tests.support.terrain_site import VALLEY_STEP_PX, TerrainSite
from tests.support.valley import Valley, ValleyDem

NADIR = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # optical x east, y south, z down


def lattice(f, x0=-10.0, y0=-10.0, n=61, spacing=1.0):
    x = x0 + spacing * np.arange(n)
    y = y0 + spacing * np.arange(n)
    X, Y = np.meshgrid(x, y)
    return Heightfield.from_array(x0, y0, spacing, f(X, Y))


def test_a_ray_meets_a_tilted_plane_where_the_algebra_says():
    # z = 0.5 x; from (0, 0, 10) along (1, 0, -1)/sqrt 2 the ray's z is 10 - s at x = s:
    # 10 - s = 0.5 s at s = 20/3, t = s sqrt 2. The bilinear surface of a plane is the plane.
    hf = lattice(lambda x, y: 0.5 * x)
    assert hf.slope_bound == pytest.approx(0.5)
    d = np.array([[1.0, 0.0, -1.0], [0.0, 0.6, -0.8], [1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = hf.first_hit_t(np.array([0.0, 0.0, 10.0]), d, 100.0)
    # (0, 0.6, -0.8): along y the plane stays at z = 0: t = 10 / 0.8. Level along x: the
    # plane rises to 10 m at x = 20. Upwards: never.
    np.testing.assert_allclose(t[:3], [20 / 3 * math.sqrt(2), 12.5, 20.0], atol=2e-3)
    assert t[3] == np.inf
    assert hf.first_hit_t(np.array([0.0, 0.0, 10.0]), d[:1], 9.0)[0] == np.inf  # t_max


def test_a_step_wall_hides_what_lies_behind_it():
    # Level ground with a 10 m wall: z = 10 for 20 <= x <= 21, ramps to 0 at x = 19 and 22.
    # From (0, 0, 15) to the ground point (40, 0, 0) the ray's z is 15 - 0.375 x; it meets the
    # ramp z = 10 (x - 19) at x = 205 / 10.375, before the wall; (10, 0, 0) is in front of it.
    hf = lattice(lambda x, y: np.clip(10 * np.minimum(x - 19, 22 - x), 0, 10), n=61)
    cam = np.array([0.0, 0.0, 15.0])
    targets = np.array([[40.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    v = targets - cam
    dist = np.linalg.norm(v, axis=1)
    t = hf.first_hit_t(cam, v / dist[:, None], dist + 1.0)
    x_hit = 205 / 10.375
    assert t[0] == pytest.approx(x_hit * math.hypot(1, 0.375), abs=2e-3)
    assert t[1] == pytest.approx(dist[1], abs=2e-3)


def test_the_valley_dem_in_utm_reads_back_as_the_valley_in_enu(tmp_path):
    # The raster is north-up in UTM 32 N (grid north 0.6 deg off true north here); reading
    # it through its CRS must give the analytic heights at ENU points, less Earth's
    # curvature (x^2 + y^2) / 2R, to within bilinear sampling twice at 1 m (the ridge's
    # curvature, 0.14 / m, makes that up to ~4 cm).
    relief = ValleyDem(Valley(300.0), spacing_m=1.0, margin_m=10.0)
    dem = relief.write_geotiff(tmp_path / "valley.tif")
    hf = Heightfield.from_dem(dem, relief.origin_lat_deg, relief.origin_lon_deg,
                              relief.floor_alt_msl_m, (-8.0, -8.0, 308.0, 308.0), 1.0)
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-8, 308, 5000), rng.uniform(-8, 308, 5000)
    curvature = (x**2 + y**2) / (2 * 6.37e6)
    np.testing.assert_allclose(hf.height_m(x, y), relief.valley.height_m(x, y) - curvature,
                               atol=0.05)
    assert relief.valley.height_m(0.0, 0.0) == pytest.approx(20.0, abs=0.01)  # the wall


def test_r3_on_level_ground_is_r1():
    # On z = 0 R3's marched and bisected first hits are R1's exact ones to 1 mm: every
    # cell's ray count agrees but for rays within 1 mm of a cell's edge.
    cam = CameraModel.from_fov(320, 240, 70.0, "plumb_bob", (-0.05, 0.01, 5e-4, -5e-4, 0.0))
    dom = Domain.from_enu([[-40, -40], [40, -40], [40, 40], [-40, 40]])
    g = dom.grid_geometry(1.0)
    det = DetectorModel.illustrative()
    hf = lattice(lambda x, y: 0.0 * x, x0=-100.0, y0=-100.0, n=201)
    pose = CameraPose(NADIR @ np.array([[1, 0, 0], [0, math.cos(0.3), -math.sin(0.3)],
                                        [0, math.sin(0.3), math.cos(0.3)]]),
                      np.array([3.0, -2.0, 30.0]))
    r1 = ReferenceGrid(g, dom.free_mask(g), cam, det, 60.0)
    r3 = TerrainReferenceGrid(g, dom.free_mask(g), cam, det, 60.0, hf, 1)
    rays = pixel_rays(cam)
    r1_update(r1, rays, pose)
    r3_update(r3, rays, pose)
    assert r1.n_obs.sum() > 1000
    assert (r1.n_obs != r3.n_obs).sum() <= 2
    assert (np.abs(r1.pd - r3.pd) > 1e-9).sum() <= 0.01 * r1.n_obs.sum()
    assert r3.n_blocked.sum() == 0 and r3.n_clear.sum() > 1000


@pytest.fixture(scope="module")
def valley(tmp_path_factory):
    """The S5 valley flight at its smoke size (200 m, 61 frames) and R3 over it, as the
    benchmark runs it (every 2nd pixel)."""
    sc = scenarios(smoke=True)["S5 valley"]
    site = TerrainSite.prepare(tmp_path_factory.mktemp("valley"), sc)
    poses = sc.poses()
    ref = site.run_reference(sc.new_grid(), poses, VALLEY_STEP_PX)
    return site, poses, ref


def test_flat_pdcov_misjudges_the_valley(valley):
    site, poses, ref = valley
    flat = site.scenario.new_grid()
    for pose in poses:
        flat.update(pose)
    a = terrain_agreement(flat, ref, R3_TOLERANCE_PD)
    assert a.hidden > 10 and a.never_seen > 100  # the valley hides ground, and ends sight
    assert a.share_within < 0.8
    assert a.never_seen_counted > 0.5 * a.never_seen and a.hidden_counted > 0


def test_pdcov_with_the_dem_agrees_with_r3(valley):
    from pdcov.core.limiting import LimitingFactor  # the terrain kernel's (issue 21)

    site, poses, ref = valley
    grid = site.terrain_grid()
    for pose in poses:
        grid.update(pose)
    a = terrain_agreement(grid, ref, R3_TOLERANCE_PD)
    assert a.hidden_counted == 0, a
    assert a.share_within >= R3_MIN_SHARE, a
    # What pdcov says limited them: the terrain, for all but cells at the picture's edge.
    assert (grid.limiting[ref.hidden] == LimitingFactor.HIDDEN).mean() >= 0.9
