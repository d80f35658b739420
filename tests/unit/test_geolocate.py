"""Geolocation of boxes and their grouping into candidates, by cases checkable by hand."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from pdcov.core.camera import CameraModel
from pdcov.core.detections import Box
from pdcov.core.domain import GridGeometry
from pdcov.core.geolocate import Geolocation, ground_points_enu, locate_boxes
from pdcov.core.pose import FixedMount, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx
from pdcov.core.terrain import TerrainSurface

CAMERA = CameraModel.from_fov(640, 480, 90.0)  # f = 320 px, centre (319.5, 239.5)
F_PX = 320.0
H_M = 20.0
EXACT = Geolocation(roll_sigma_rad=0, pitch_sigma_rad=0, yaw_sigma_rad=0,
                    horizontal_sigma_m=0, vertical_sigma_m=0, pixel_sigma_px=0)


def nadir(x_m=0.0, y_m=0.0, h_m=H_M, yaw_rad=0.0, roll_rad=0.0):
    """A level vehicle heading ``yaw_rad`` with a nadir camera: image up is the heading."""
    return fixed_mount_pose(R_from_euler_zyx(roll_rad, 0.0, yaw_rad), np.array([x_m, y_m, h_m]),
                            FixedMount())


def box_at(x_px, y_px, cls="car"):
    """A 10 x 10 px box centred on (x_px, y_px)."""
    return Box(cls, 0.9, x_px - 5, y_px - 5, 10, 10)


def test_nadir_centre_and_pixel_offsets_map_to_h_d_over_f():
    d = 64.0
    boxes = [box_at(319.5, 239.5), box_at(319.5 + d, 239.5), box_at(319.5, 239.5 - d)]
    p, sigma = locate_boxes(CAMERA, nadir(5.0, 7.0), boxes, EXACT)
    # Heading north: image right is east, image up is north.
    np.testing.assert_allclose(p, [[5, 7, 0], [5 + H_M * d / F_PX, 7, 0],
                                   [5, 7 + H_M * d / F_PX, 0]], atol=1e-9)
    np.testing.assert_allclose(sigma, 0.0, atol=1e-12)


def test_a_standing_person_is_located_at_the_feet():
    person = Box("person", 0.9, 309.5, 139.5, 20.0, 100.0)  # bottom centre (319.5, 239.5)
    car = Box("car", 0.9, 309.5, 139.5, 20.0, 100.0)  # centre 50 px above: 50/320*20 m north
    p, _ = locate_boxes(CAMERA, nadir(), [person, car], EXACT)
    np.testing.assert_allclose(p, [[0, 0, 0], [0, H_M * 50 / F_PX, 0]], atol=1e-9)


def test_sigma_of_each_error_by_hand():
    centre = [box_at(319.5, 239.5)]
    pixel = Geolocation(**{**_zero(), "pixel_sigma_px": 3.0})
    assert locate_boxes(CAMERA, nadir(), centre, pixel)[1][0] == pytest.approx(H_M * 3 / F_PX)
    e = math.radians(0.5)
    for name in ("roll_sigma_rad", "pitch_sigma_rad"):
        g = Geolocation(**{**_zero(), name: e})
        # h tan(e) over +-e: the central difference of h tan is h tan(e) / e per radian.
        assert locate_boxes(CAMERA, nadir(yaw_rad=1.0), centre, g)[1][0] == pytest.approx(
            H_M * math.tan(e), rel=1e-9)
    yaw = Geolocation(**{**_zero(), "yaw_sigma_rad": e})
    assert locate_boxes(CAMERA, nadir(), centre, yaw)[1][0] == pytest.approx(0.0, abs=1e-9)
    off = [box_at(319.5 + 160, 239.5)]  # 10 m east of the camera: yaw moves it 10 e m
    assert locate_boxes(CAMERA, nadir(), off, yaw)[1][0] == pytest.approx(
        10 * math.sin(e), rel=1e-6)
    horiz = Geolocation(**{**_zero(), "horizontal_sigma_m": 1.5})
    assert locate_boxes(CAMERA, nadir(), centre, horiz)[1][0] == pytest.approx(1.5)
    vert = Geolocation(**{**_zero(), "vertical_sigma_m": 2.0})
    assert locate_boxes(CAMERA, nadir(), centre, vert)[1][0] == pytest.approx(0.0, abs=1e-9)
    assert locate_boxes(CAMERA, nadir(), off, vert)[1][0] == pytest.approx(10 / H_M * 2.0)


def test_the_largest_direction_is_reported():
    g = Geolocation(**{**_zero(), "horizontal_sigma_m": 1.0, "pixel_sigma_px": 16.0})
    # Pixel: 1 m each way; position: 1 m each way: C = 2 I, sigma sqrt(2).
    assert locate_boxes(CAMERA, nadir(), [box_at(319.5, 239.5)], g)[1][0] == pytest.approx(
        math.sqrt(2))


def test_rays_that_miss_give_nan():
    tilted = nadir(roll_rad=math.radians(80))  # camera looking 10 deg below the horizon...
    p, sigma = locate_boxes(CAMERA, tilted, [box_at(0, 239.5), box_at(639, 239.5)],
                            Geolocation())
    # ... one edge of the picture sees sky: NaN there, a far ground point at the other.
    assert np.isnan(p[:, 0]).sum() == 1 and np.isnan(sigma).sum() == 1


def test_terrain_intersection_matches_the_surface():
    g = GridGeometry(-50.0, -50.0, 1.0, 100, 100)
    x, y = np.meshgrid(np.arange(101) - 50.0, np.arange(101) - 50.0)
    terrain = TerrainSurface(g, 0.2 * x + 3.0)  # a 0.2 slope rising east, 3 m at x = 0
    rng = np.random.default_rng(1)
    d = rng.normal(size=(50, 3)) * [0.3, 0.3, 0.0] + [0, 0, -1.0]
    p = ground_points_enu(np.tile([0.0, 0.0, 30.0], (50, 1)), d, terrain)
    np.testing.assert_allclose(p[:, 2], 0.2 * p[:, 0] + 3.0, atol=1e-6)
    # Through the point itself: the straight-down ray at x = 10 meets z = 5.
    np.testing.assert_allclose(ground_points_enu(np.array([[10.0, 0, 30]]),
                                                 np.array([[0, 0, -1.0]]), terrain),
                               [[10, 0, 5]], atol=1e-9)
    up = ground_points_enu(np.array([[0.0, 0, 30]]), np.array([[1.0, 0, 0.1]]), terrain)
    assert np.isnan(up).all()


def _zero() -> dict:
    return {"roll_sigma_rad": 0.0, "pitch_sigma_rad": 0.0, "yaw_sigma_rad": 0.0,
            "horizontal_sigma_m": 0.0, "vertical_sigma_m": 0.0, "pixel_sigma_px": 0.0}


def _tracker(gate_sigmas: float = 3.0):
    from pdcov.detection.candidates import DetectionTracker
    return DetectionTracker(CAMERA, Geolocation(**{**_zero(), "pixel_sigma_px": 1.6}), 1.0,
                            gate_sigmas=gate_sigmas)


def test_grouping_joins_within_the_gate_and_weights_by_variance():
    # Pixel sigma 1.6 px at 20 m: 0.1 m per detection; gate 3 * hypot(0.1, 0.1) = 0.42 m.
    t = _tracker()
    px_per_m = F_PX / H_M
    a = t.frame(nadir(), 1.0, [box_at(319.5, 239.5)])  # (0, 0)
    b = t.frame(nadir(), 1.2, [box_at(319.5 + 0.4 * px_per_m, 239.5),  # 0.4 m east: joins
                               box_at(319.5 + 0.5 * px_per_m, 239.5),  # 0.5 m: a new one
                               box_at(319.5, 239.5, cls="truck")])  # another class
    assert [d.candidate_id for d in a + b] == [0, 0, 1, 2]
    from pdcov.config.load import load_mission
    grid = load_mission(Path(__file__).resolve().parents[2]
                        / "service/pdcov/data/demo_mission.yaml").new_mission_grid()
    c0 = t.candidates(grid)[0]
    assert (c0.hits, c0.first_t_boot_s, c0.last_t_boot_s) == (2, 1.0, 1.2)
    np.testing.assert_allclose(c0.r_enu_m, [0.2, 0, 0], atol=1e-9)  # equal weights: the mean
    assert c0.sigma_m == pytest.approx(0.1 / math.sqrt(2))
    # No grid given to frame: each frame with a box a look and a hit; the grid's P_D 0.
    assert c0.looks == 2 and c0.pd == 0.0
    assert [c.candidate_id for c in t.candidates(grid, [2, 0])] == [0, 2]


def test_grouping_is_deterministic_and_nearest_wins():
    def run():
        t = _tracker()
        px_per_m = F_PX / H_M
        t.frame(nadir(), 1.0, [box_at(319.5, 239.5), box_at(319.5 + 0.6 * px_per_m, 239.5)])
        # 0.35 m from the first, 0.25 m from the second (both in the 0.42 m gate): joins
        # the second.
        return [(d.candidate_id, d.r_enu_m.tolist(), d.sigma_m)
                for d in t.frame(nadir(), 1.1, [box_at(319.5 + 0.35 * px_per_m, 239.5)])]
    assert run()[0][0] == 1 and run() == run()


def test_candidate_budget_evicts_the_stalest_unconfirmed_never_a_confirmed_one(monkeypatch):
    import pdcov.detection.candidates as cands
    monkeypatch.setattr(cands, "MAX_CANDIDATES_PER_CLASS", 3)
    monkeypatch.setattr(cands, "MAX_TRACKED_CANDIDATES", 4)
    t = _tracker()
    px_per_m = F_PX / H_M

    def at(x_m: float, cls: str = "person"):
        return box_at(319.5 + x_m * px_per_m, 239.5, cls=cls)

    t.frame(nadir(), 1.0, [at(0.0)])
    t.frame(nadir(), 1.1, [at(0.0)])  # candidate 0 confirmed (2 hits)
    t.frame(nadir(), 2.0, [at(3.0), at(6.0)])  # 1, 2: unconfirmed; the class is full
    (d,) = t.frame(nadir(), 3.0, [at(-3.0)])  # evicts 1 (the stalest unconfirmed), not 0
    assert d.candidate_id == 3 and sorted(t._groups) == [0, 2, 3]
    # 10,000 invented classes fill the table; a real person still makes a candidate.
    for k in range(10):
        t.frame(nadir(), 4.0 + k, [at(-6.0, cls=f"invented{k}")])
    (d,) = t.frame(nadir(), 20.0, [at(9.0)])
    assert d.candidate_id in t._groups and 0 in t._groups
    assert t.skipped[cands.Skip.EVICTED] >= 2
    # Only confirmed candidates of the class left: the new box is counted, none evicted.
    full = _tracker()
    for x in (0.0, 3.0, 6.0):
        full.frame(nadir(), 1.0, [at(x)])
        full.frame(nadir(), 1.1, [at(x)])
    assert full.frame(nadir(), 2.0, [at(-3.0)]) == []
    assert full.skipped[cands.Skip.TOO_MANY_CANDIDATES] == 1 and len(full) == 3
