"""False alarms as a rate per image area: the fit recovers a known rate, the grid's P_FA per
look is 1 - exp(-rate A) on a nadir cell checked by hand, old model files warn."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import optimize, stats

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import FixedMount, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx
from pdcov.detection.bins import false_box_rate
from pdcov.detection.matching import MatchSettings, match_images
from pdcov.detection.statistics import fit_binned
from pdcov.detection.truth_set import Boxes, ImageTruth
from pdcov.errors import DetectorModelError

EDGES = (8.0, 16.0, 32.0, 64.0)  # detector-input px
RATE_PER_MPX = (40.0, 15.0, 5.0)  # false boxes per frame per Mpx of detector input, by bin
WIDTH, HEIGHT, INPUT = 1280, 720, 640  # scale 0.5: each frame is 640 x 360 = 0.2304 Mpx input
N_FRAMES = 400


def labelled_frames(seed: int = 7):
    """Frames with one person detected each (true boxes, not false alarms) and false boxes
    placed at random: per bin a Poisson number at RATE_PER_MPX times the frame's input area,
    sizes log-uniform in the bin (scaled to image px)."""
    rng = np.random.default_rng(seed)
    scale = INPUT / max(WIDTH, HEIGHT)
    area_mpx = WIDTH * HEIGHT * scale**2 / 1e6
    frames = []
    for k in range(N_FRAMES):
        person = [20.0, 20.0, 40.0, 40.0]  # 20 px input: bin [16, 32)
        rows, scores = [person], [0.9]
        for i, rate in enumerate(RATE_PER_MPX):
            lo, hi = EDGES[i], EDGES[i + 1]
            for _ in range(rng.poisson(rate * area_mpx)):
                side = math.exp(rng.uniform(math.log(lo), math.log(hi))) / scale
                x = rng.uniform(100, WIDTH - side)  # away from the person
                y = rng.uniform(100, HEIGHT - side)
                rows.append([x, y, side, side])
                scores.append(0.8)
        truth = ImageTruth(f"f{k}", WIDTH, HEIGHT, Boxes.from_rows([person], ["person"]))
        frames.append((truth, Boxes.from_rows(rows, ["person"] * len(rows), scores)))
    return frames


def test_fit_recovers_a_known_false_box_rate_within_its_interval():
    matches = match_images(labelled_frames(), MatchSettings(input_size_px=INPUT))
    assert matches.image_area_mpx == pytest.approx(N_FRAMES * 0.2304)
    model = fit_binned(matches, EDGES)
    rate = np.array(model.fa_rate_per_mpx)
    ci = np.array(model.extra["fa_rate_per_mpx_ci95"])
    n_false = np.array(model.extra["n_false_boxes"])
    # The rate is the false boxes over the area, the person's true boxes not among them.
    np.testing.assert_allclose(rate, n_false / (N_FRAMES * 0.2304), rtol=1e-5)
    assert model.counts is not None
    assert int(np.sum(model.counts.n_detections) - n_false.sum()) == N_FRAMES
    assert np.all((ci[:, 0] <= RATE_PER_MPX) & (RATE_PER_MPX <= ci[:, 1])), (rate, ci)
    # The paper's 1 - precision is kept beside it: in bin [16, 32) one true box a frame.
    assert model.p_false_alarm[1] == pytest.approx(n_false[1] / (n_false[1] + N_FRAMES),
                                                   abs=1e-6)


def test_garwood_interval_against_the_poisson_cdf():
    # Independent oracle: the exact bounds solve P(X >= n | lo) = 0.025, P(X <= n | hi) = 0.025.
    for n in (0, 1, 7, 60):
        _, lo, hi = false_box_rate(np.array([n]), 2.0)
        want_hi = optimize.brentq(lambda m, n=n: stats.poisson.cdf(n, m) - 0.025, 1e-9, 500)
        assert hi[0] * 2.0 == pytest.approx(want_hi, rel=1e-6)
        if n == 0:
            assert lo[0] == 0.0
        else:
            want_lo = optimize.brentq(lambda m, n=n: stats.poisson.sf(n - 1, m) - 0.025,
                                      1e-9, 500)
            assert lo[0] * 2.0 == pytest.approx(want_lo, rel=1e-6)


def test_worked_example_of_the_docs():
    m = DetectorModel.from_dict({"version": 4, "bin_edges_px": [10, 40],
                                 "p_detect": [0.5], "p_false_alarm": [0.3],
                                 "fa_rate_per_mpx": [2.0], "input_size_px": None})
    # 2 false boxes per Mpx, a cell of 20 x 20 = 400 px^2: 1 - exp(-0.0008).
    p = m.p_false_alarm_per_look(np.array([20.0]), np.array([400.0]))
    assert p[0] == pytest.approx(1 - math.exp(-0.0008), rel=1e-12)
    assert p[0] == pytest.approx(0.0008, rel=1e-3)


def nadir_grid(input_size_px: int | None, width_px: int, height_px: int, fa_rate: float):
    f = 500.0
    cam = CameraModel(width_px, height_px, np.array(
        [[f, 0, (width_px - 1) / 2], [0, f, (height_px - 1) / 2], [0, 0, 1]]))
    det = DetectorModel.from_dict({
        "version": 4, "bin_edges_px": [1, 2000], "p_detect": [0.5], "p_false_alarm": [0.3],
        "fa_rate_per_mpx": [fa_rate], "input_size_px": input_size_px})
    dom = Domain.from_enu([[-20, -20], [20, -20], [20, 20], [-20, 20]])
    g = dom.grid_geometry(1.0)
    # Camera 10 m above the centre of cell (20, 20), looking straight down (yaw 0).
    pose = fixed_mount_pose(R_from_euler_zyx(0.0, 0.0, 0.0), (0.5, 0.5, 10.0), FixedMount(),
                            0.0)
    return CoverageGrid(g, dom.free_mask(g), cam, det), pose


@pytest.mark.parametrize("input_size_px, width_px, height_px, cell_input_px2", [
    (None, 640, 480, 2500.0),   # f = 500 px, 1 m at 10 m: 50 px a side, 2,500 px^2
    (640, 1280, 960, 625.0),    # letterboxed to 640: scale 0.5, 25 px a side, 625 px^2
])
def test_grid_p_fa_per_look_on_a_nadir_cell_by_hand(input_size_px, width_px, height_px,
                                                     cell_input_px2):
    grid, pose = nadir_grid(input_size_px, width_px, height_px, fa_rate=200.0)
    grid.update(pose)
    observed, size = grid.observe(pose, (20, 21, 20, 21))
    assert observed[0, 0] and size[0] == pytest.approx(50.0, rel=1e-6)
    want = 1 - math.exp(-200e-6 * cell_input_px2)
    assert grid.pfa[20, 20] == pytest.approx(want, rel=1e-5)
    # Accumulated across looks as before: two independent looks, 1 - (1 - p)^2.
    grid.update(pose)
    assert grid.pfa[20, 20] == pytest.approx(1 - (1 - want) ** 2, rel=1e-5)
    # Every observed cell: 1 - exp(-rate A), A its image area in detector-input px^2.
    obs, size = grid.observe(pose, (0, 40, 0, 40))
    scale = grid.size_scale
    a_input = (size * scale) ** 2
    np.testing.assert_allclose(grid.pfa[obs], -np.expm1(-2 * 200e-6 * a_input), rtol=1e-4)


def test_an_old_model_file_loads_with_one_warning_and_no_false_alarms():
    doc = {"version": 3, "bin_edges_px": [1, 2000], "p_detect": [0.5],
           "p_false_alarm": [0.3], "input_size_px": None}
    with pytest.warns(UserWarning, match=r"old.yaml: version 3 has no fa_rate_per_mpx .*1 - "
                                         r"precision.*Refit with `pdcov detector fit`"):
        m = DetectorModel.from_dict(doc, source="old.yaml")
    assert m.fa_rate_per_mpx is None
    assert m.to_dict()["version"] == 1  # written back as read: no rate invented
    assert np.all(m.padded_fa_rate_per_px2_by_blur() == 0)


def test_the_rate_is_refused_where_it_is_wrong():
    base = {"bin_edges_px": [1, 10, 2000], "p_detect": [0.5, 0.6],
            "p_false_alarm": [0.3, 0.2], "input_size_px": None}
    with pytest.raises(DetectorModelError, match=r"m.yaml: fa_rate_per_mpx: missing"):
        DetectorModel.from_dict({"version": 4, **base}, source="m.yaml")
    with pytest.raises(DetectorModelError, match=r"fa_rate_per_mpx: needs version 4"):
        DetectorModel.from_dict({"version": 3, **base, "fa_rate_per_mpx": [1.0, 2.0]})
    with pytest.raises(DetectorModelError, match=r"fa_rate_per_mpx: expected 2 finite"):
        DetectorModel.from_dict({"version": 4, **base, "fa_rate_per_mpx": [1.0, -2.0]})
    m = DetectorModel.from_dict({"version": 4, **base, "fa_rate_per_mpx": [1.0, 2.0]})
    assert DetectorModel.from_dict(m.to_dict()).fa_rate_per_mpx == (1.0, 2.0)
