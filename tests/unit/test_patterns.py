"""Coverage patterns: tracks in free space, requested spacing, full footprint coverage."""

from __future__ import annotations

import math

import numpy as np
import pytest
from shapely.geometry import LineString, Point, Polygon, box

from pdcov.core.domain import Domain
from pdcov.errors import ConfigError
from pdcov.planning import patterns as P
from pdcov.planning.decomposition import boustrophedon_decomposition

OUTER = [(0, 0), (30, 0), (30, 10), (45, 5), (60, 12), (60, 40), (40, 45), (35, 30),
         (25, 45), (0, 40), (8, 20)]
OBSTACLE = [(20, 15), (32, 12), (38, 22), (28, 28), (24, 22)]
FIG3 = Domain.from_enu(OUTER, [OBSTACLE]).free_space
SQUARE = Polygon([(-60, -60), (-60, -20), (-20, -20), (-20, -60)])  # the paper's IV-C area

SWATH_M = 8.0
SPACING_M = P.track_spacing_m(SWATH_M, 0.2)


def in_free_space(plan, free):
    return free.buffer(1e-4).covers(LineString(plan.xy_enu_m))


def covered_fraction(plan, free, swath_m=SWATH_M):
    # A disk of the swath's diameter fits inside a nadir footprint that wide, so the path
    # buffered by half the swath is what such a camera sees at the least.
    seen = LineString(plan.xy_enu_m).buffer(swath_m / 2)
    return seen.intersection(free).area / free.area


def test_spacing_from_swath_and_overlap():
    assert P.track_spacing_m(10.0, 0.25) == pytest.approx(7.5)
    with pytest.raises(ConfigError, match="overlap"):
        P.track_spacing_m(10.0, 1.0)
    with pytest.raises(ConfigError, match="swath"):
        P.track_spacing_m(0.0, 0.2)


def test_swath_of_rotated_rectangle():
    fp = box(-6, -4, 6, 4)  # 12 m east-west, 8 m north-south
    assert P.swath_width_m(fp, 0.0) == pytest.approx(12.0)  # flying north: across is east
    assert P.swath_width_m(fp, math.pi / 2) == pytest.approx(8.0)
    assert P.swath_width_m(fp, math.pi / 4) == pytest.approx(20 / math.sqrt(2))


@pytest.mark.parametrize("heading_deg", [0, 30, 90, 117])
@pytest.mark.parametrize("free", [FIG3, SQUARE], ids=["fig3", "square"])
def test_lawnmower_in_free_space_with_requested_spacing_and_full_coverage(free, heading_deg):
    heading = math.radians(heading_deg)
    plan = P.lawnmower(free, SPACING_M, heading, 10.0, 5.0)
    assert in_free_space(plan, free)
    # Where a cell's first or last track ends short of an acute corner, a sliver up to half a
    # spacing wide can stay unseen (docs/planning.md, limits).
    assert covered_fraction(plan, free) > 0.997
    assert all(w.alt_agl_m == 10.0 and w.speed_mps == 5.0 for w in plan.waypoints)
    # Within each cell the tracks run along the heading, exactly SPACING_M apart.
    d = boustrophedon_decomposition(free, -heading)
    along = P.unit_of_heading(heading)
    across = P.unit_of_heading(heading + math.pi / 2)
    for tracks in P.cell_tracks(d, SPACING_M):
        for seg in tracks:
            v = seg[1] - seg[0]
            assert abs(v @ across) < 1e-6 * max(1.0, np.linalg.norm(v))
            assert free.buffer(1e-6).covers(LineString(seg))
        offsets = [float(seg[0] @ across) for seg in tracks]
        assert np.allclose(np.diff(offsets), SPACING_M) or len(offsets) == 1
    assert np.linalg.norm(along) == pytest.approx(1.0)


def test_lawnmower_flies_every_track():
    plan = P.lawnmower(SQUARE, SPACING_M, 0.0, 10.0, 5.0)
    path = LineString(plan.xy_enu_m).buffer(1e-6)
    tracks = P.cell_tracks(boustrophedon_decomposition(SQUARE, 0.0), SPACING_M)[0]
    assert len(tracks) == math.ceil(40 / SPACING_M)
    assert all(path.covers(LineString(t)) for t in tracks)


@pytest.mark.parametrize("free", [FIG3, SQUARE], ids=["fig3", "square"])
def test_spiral_in_free_space_and_covers(free):
    plan = P.spiral(free, SPACING_M, 10.0, 5.0)
    assert in_free_space(plan, free)
    assert covered_fraction(plan, free) > 0.999


def test_spiral_turns_are_spacing_apart():
    centre = np.array([0.0, 0.0])
    big = box(-100, -100, 100, 100)
    xy = P.spiral(big, 5.0, 10.0, 5.0, centre_enu_m=centre).xy_enu_m
    xy = xy[np.linalg.norm(xy - centre, axis=1) < 95.0]  # before the box clips it
    r = np.linalg.norm(xy - centre, axis=1)
    theta = np.unwrap(np.arctan2(xy[:, 1], xy[:, 0]))
    # Archimedean: r grows by one spacing per turn (to the 5 cm simplification tolerance).
    assert np.allclose(r[5:], 5.0 * (theta[5:] - theta[0]) / (2 * math.pi), atol=0.1)


def test_expanding_square_legs_and_coverage():
    plan = P.expanding_square(box(-100, -100, 100, 100), 10.0, 10.0, 5.0,
                              datum_enu_m=np.zeros(2), heading_rad=0.0)
    xy = plan.xy_enu_m
    legs = np.diff(xy[:7], axis=0)
    assert np.allclose(np.linalg.norm(legs, axis=1), [10, 10, 20, 20, 30, 30])
    # First leg north, then right turns: east, south, west.
    assert np.allclose(legs[:4] / np.linalg.norm(legs[:4], axis=1)[:, None],
                       [[0, 1], [1, 0], [0, -1], [-1, 0]])
    sq_plan = P.expanding_square(SQUARE, SPACING_M, 10.0, 5.0)
    assert in_free_space(sq_plan, SQUARE)
    assert covered_fraction(sq_plan, SQUARE) > 0.999


def test_sector_search_geometry():
    plan = P.sector_search(box(-100, -100, 100, 100), 10.0, 5.0, datum_enu_m=np.zeros(2),
                           heading_rad=0.0, radius_m=30.0)
    xy = plan.xy_enu_m
    assert len(xy) == 10
    bearings = np.degrees(np.arctan2(xy[:, 0], xy[:, 1])) % 360
    r = np.linalg.norm(xy, axis=1)
    assert np.allclose(r[[1, 2, 4, 5, 7, 8]], 30.0)
    assert np.allclose(bearings[[1, 2, 4, 5, 7, 8]], [0, 60, 240, 300, 120, 180], atol=1e-9)
    assert np.allclose(r[[0, 3, 6, 9]], 0.0)


def test_router_goes_round_an_obstacle():
    free = Domain.from_enu([(0, 0), (10, 0), (10, 10), (0, 10)],
                           [[(4, 2), (6, 2), (6, 8), (4, 8)]]).free_space
    path = P.FreeSpaceRouter(free).path(np.array([2.0, 5.0]), np.array([8.0, 5.0]))
    line = LineString(path)
    assert free.buffer(1e-6).covers(line)
    # Shortest way: over the obstacle's corners at y = 2 or y = 8.
    assert line.length == pytest.approx(2 * math.hypot(2, 3) + 2, rel=1e-9)


def test_pattern_outside_free_space_is_refused():
    with pytest.raises(ConfigError, match="free space"):
        P.sector_search(SQUARE, 10.0, 5.0, datum_enu_m=np.array([500.0, 500.0]),
                        radius_m=10.0)


L_SHAPE = Polygon([(0, 0), (100, 0), (100, 30), (30, 30), (30, 100), (0, 100)])


def test_default_datum_of_an_l_shaped_domain_is_inside_it():
    # The smallest circle around the L is centred in its notch, outside the L.
    c = P.auto_centre_enu_m(L_SHAPE)
    assert not L_SHAPE.contains(Point(c))
    d = P.default_datum_enu_m(L_SHAPE)
    assert L_SHAPE.contains(Point(d))
    # The point of the L farthest from its edges, on its diagonal: (a, a) as far from the
    # outer edges as from the inner corner, a = sqrt(2) (30 - a).
    a = 30 * math.sqrt(2) / (1 + math.sqrt(2))
    assert np.allclose(d, [a, a], atol=0.2)
    for plan in (P.expanding_square(L_SHAPE, 10.0, 10.0, 5.0),
                 P.sector_search(L_SHAPE, 10.0, 5.0)):
        assert np.allclose(plan.xy_enu_m[0], d)  # the pattern starts at the datum it names
        assert f"datum ({d[0]:.1f}, {d[1]:.1f}) m" in plan.description


def test_datum_outside_the_free_space_is_refused_naming_the_nearest_free_point():
    for build in (lambda d: P.expanding_square(L_SHAPE, 10.0, 10.0, 5.0, datum_enu_m=d),
                  lambda d: P.sector_search(L_SHAPE, 10.0, 5.0, datum_enu_m=d,
                                            radius_m=20.0)):
        with pytest.raises(ConfigError, match=r"datum \(60, 50\) m .* outside the free "
                                              r"space.* nearest free point is \(60\.0, 29\.9\)"):
            build(np.array([60.0, 50.0]))
    # On the boundary is inside.
    assert np.allclose(P.sector_search(L_SHAPE, 10.0, 5.0, datum_enu_m=np.array([30.0, 30.0]),
                                       radius_m=5.0).xy_enu_m[0], [30, 30])


def turns_deg(xy):
    d = np.diff(xy, axis=0)
    h = np.degrees(np.arctan2(d[:, 0], d[:, 1]))
    return (np.diff(h) + 180) % 360 - 180  # > 0: right turn


def test_expanding_square_off_centre_keeps_its_shape_and_reports_coverage():
    free = box(0, 0, 400, 400)
    plan = P.expanding_square(free, 20.0, 10.0, 5.0, datum_enu_m=np.array([60.0, 200.0]))
    xy = plan.xy_enu_m
    # Right turns of 90 deg only (clipping used to fly the west edge back and forth with
    # left turns and reversals, 13.7 km); legs 1, 1, 2, 2, ... spacings, the last one
    # ending on the boundary, where the pattern ends.
    assert np.allclose(turns_deg(xy), 90.0)
    legs = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    assert np.allclose(legs[:-1], 20.0 * (np.arange(len(legs) - 1) // 2 + 1))
    assert legs[-1] <= 20.0 * ((len(legs) - 1) // 2 + 1) + 1e-9
    assert xy[-1][0] == pytest.approx(0.0)  # stopped at the west edge
    assert in_free_space(plan, free)
    # The square stops growing at the west edge, 60 m from the datum: it covers a small
    # part of the domain, and says so (half a spacing around the legs).
    share = LineString(xy).buffer(10.0, join_style="mitre").intersection(free).area / free.area
    assert 0.10 < share < 0.20
    assert plan.description.endswith(f"covers {share:.0%} of the free space")


def test_sector_default_radius_keeps_the_triangles_inside():
    free = box(0, 0, 400, 400)
    for datum in ([200.0, 200.0], [100.0, 220.0]):
        d = np.array(datum)
        plan = P.sector_search(free, 10.0, 5.0, datum_enu_m=d)
        xy = plan.xy_enu_m
        assert len(xy) == 10 and in_free_space(plan, free)
        r = np.linalg.norm(xy - d, axis=1)
        assert np.allclose(r[[0, 3, 6, 9]], 0.0)
        radius = r[1]
        assert np.allclose(r[[1, 2, 4, 5, 7, 8]], radius)
        # Right turns of 120 deg at the vertices, straight on through the datum.
        assert np.allclose(np.sort(np.abs(turns_deg(xy))), [0, 0] + [120] * 6, atol=1e-6)
        # The largest such radius: 1 % more and a vertex would be outside.
        bigger = d + 1.01 * (xy[[1, 2, 4, 5, 7, 8]] - d)
        assert not all(free.covers(Point(p)) for p in bigger)
        named = float(plan.description.split("radius ")[1].split(" m")[0])
        assert named == pytest.approx(radius, abs=1e-3)
    # Centred in the square: the vertices north and south touch the edges (radius 200).
    centred = P.sector_search(free, 10.0, 5.0)
    assert np.linalg.norm(centred.xy_enu_m[1] - [200, 200]) == pytest.approx(200.0, abs=0.02)


def test_sector_second_pattern_turned_30_deg():
    d = np.zeros(2)
    plan = P.sector_search(box(-100, -100, 100, 100), 10.0, 5.0, datum_enu_m=d,
                           heading_rad=0.0, radius_m=30.0, second=True)
    xy = plan.xy_enu_m
    assert len(xy) == 19 and "second pattern turned 30 deg" in plan.description
    bearings = np.degrees(np.arctan2(xy[:, 0], xy[:, 1])) % 360
    assert np.allclose(bearings[[1, 2, 4, 5, 7, 8]], [0, 60, 240, 300, 120, 180], atol=1e-9)
    assert np.allclose(bearings[[10, 11, 13, 14, 16, 17]], [30, 90, 270, 330, 150, 210],
                       atol=1e-9)
    assert np.allclose(np.linalg.norm(xy[[0, 3, 6, 9, 12, 15, 18]], axis=1), 0.0)


def test_sector_with_a_radius_past_the_boundary_ends_there_and_says_how_much_it_covers():
    free = box(0, 0, 400, 400)
    plan = P.sector_search(free, 10.0, 5.0, datum_enu_m=np.array([200.0, 200.0]),
                           radius_m=250.0)
    xy = plan.xy_enu_m
    # First leg north to the edge, and no further: no flight along the boundary.
    assert np.allclose(xy, [[200, 200], [200, 400]])
    assert plan.description.endswith("covers 0% of the free space")
    whole = P.sector_search(free, 10.0, 5.0, datum_enu_m=np.array([200.0, 200.0]))
    hexagon = 3 * math.sqrt(3) / 2 * 200.0 ** 2 / 400.0 ** 2
    assert whole.description.endswith(f"covers {hexagon:.0%} of the free space")
