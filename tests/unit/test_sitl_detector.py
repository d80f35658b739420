"""The simulator's people and simulated detector in memory (pdcov_sitl/targets.py,
pdcov_sitl/detector.py): placement and the targets file, the person's apparent size against
the coverage grid's own, boxes standing on the feet's pixel, detection and false-alarm
draws at the model's probabilities, and the look interval."""

from __future__ import annotations

import numpy as np
import pytest

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.detector_sections import ConfidenceModel
from pdcov.core.domain import Domain
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose
from pdcov.errors import InputFileError
from pdcov_sitl.cli import main as sitl_main
from pdcov_sitl.detector import FALSE_ALARM_ID, DetectorOptions, SimulatedDetector
from pdcov_sitl.targets import Targets, on_ground, place_targets, read_targets

R_NADIR = np.diag([1.0, -1.0, -1.0])  # optical x east, y south, z down
CAMERA = CameraModel.from_fov(640, 480, 67.4)
DOMAIN = Domain.from_enu([[0, 0], [40, 0], [40, 40], [0, 40]],
                         [[[10, 10], [20, 10], [20, 20], [10, 20]]])


def model(p_d: float, fa_rate_per_mpx: float) -> DetectorModel:
    return DetectorModel((1.0, 1000.0), (p_d,), (0.0,), (fa_rate_per_mpx,), input_size_px=640,
                         confidence_threshold=0.5)


def grid(detector: DetectorModel) -> CoverageGrid:
    g = DOMAIN.grid_geometry(1.0)
    return CoverageGrid(g, DOMAIN.free_mask(g), CAMERA, detector)


def nadir(x_m: float, y_m: float, z_m: float, t_s: float = 0.0) -> CameraPose:
    return CameraPose(R_NADIR, np.array([x_m, y_m, z_m]), t_s)


def test_placed_people_lie_in_the_free_space_and_repeat_for_a_seed():
    a = place_targets(500, DOMAIN, None, seed=3)
    assert len(a) == 500
    x, y, z = a.r_enu_m.T
    assert ((0 <= x) & (x <= 40) & (0 <= y) & (y <= 40)).all() and (z == 0).all()
    assert not ((10 < x) & (x < 20) & (10 < y) & (y < 20)).any()  # the obstacle
    np.testing.assert_array_equal(a.r_enu_m, place_targets(500, DOMAIN, None, 3).r_enu_m)
    assert not np.array_equal(a.r_enu_m, place_targets(500, DOMAIN, None, 4).r_enu_m)


def test_targets_file_with_and_without_header(tmp_path):
    f = tmp_path / "t.csv"
    f.write_text("x_m,y_m\n1.5, 2\n\n-3,4.25\n")
    np.testing.assert_array_equal(read_targets(f, None).r_enu_m,
                                  [[1.5, 2, 0], [-3, 4.25, 0]])
    f.write_text("1,2\n")
    assert len(read_targets(f, None)) == 1


@pytest.mark.parametrize("text, line", [("x_m,y_m\n1,2\n3\n", 3), ("1,2,3\n", 1),
                                        ("1,two\n", 1), ("1,2\nnan,1\n", 2)])
def test_a_bad_targets_row_names_its_line(tmp_path, text, line):
    f = tmp_path / "t.csv"
    f.write_text(text)
    with pytest.raises(InputFileError, match=rf"t\.csv: line {line}: "):
        read_targets(f, None)


def test_cli_refuses_a_bad_targets_file_in_one_line(tmp_path, capsys):
    from importlib import resources

    f = tmp_path / "t.csv"
    f.write_text("1,2\n1;2\n")
    with resources.as_file(resources.files("pdcov") / "data" / "demo_mission.yaml") as cfg:
        code = sitl_main(["fly", "--config", str(cfg), "--plan", str(tmp_path / "p.plan"),
                          "--out", str(tmp_path / "out"), "--targets", str(f)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "t.csv: line 2: expected x_m,y_m" in err[0]
    code = sitl_main(["fly", "--config", str(cfg), "--plan", str(tmp_path / "p.plan"),
                      "--out", str(tmp_path / "out"), "--targets", "5",
                      "--box-noise-px", "-1"])
    assert code == 2 and "--box-noise-px -1.0: expected" in capsys.readouterr().err


def test_person_size_is_the_grid_cells_size_where_a_person_stands_at_a_cell_centre():
    """Independent of the grid's kernel, the two agree where they measure the same square."""
    g = grid(model(1.0, 0.0))
    xs, ys = np.meshgrid(np.arange(24.5, 36), np.arange(24.5, 36))
    people = on_ground(xs.ravel(), ys.ravel(), None)
    det = SimulatedDetector(g, people, DetectorOptions(), 0)
    pose = CameraPose(R_NADIR @ np.array([[1, 0, 0], [0, np.cos(0.3), -np.sin(0.3)],
                                          [0, np.sin(0.3), np.cos(0.3)]]),
                      np.array([30.0, 27.0, 9.0]), 0.0)
    in_view, size = det.person_sizes_px(pose)
    observed, cell_size = g.observe(pose, (0, 40, 0, 40))
    rows, cols = g.geometry.cell_of(xs.ravel(), ys.ravel())
    seen = observed[rows, cols]
    sizes = np.full(observed.shape, np.nan)
    sizes[observed] = cell_size
    np.testing.assert_array_equal(in_view, seen)
    assert in_view.sum() > 50
    np.testing.assert_allclose(size[in_view], sizes[rows, cols][in_view], rtol=1e-6)
    # Straight below a nadir camera at 10 m a 1 m square spans f / 10 pixels a side.
    det1 = SimulatedDetector(g, on_ground([30.0], [30.0], None), DetectorOptions(), 0)
    np.testing.assert_allclose(det1.person_sizes_px(nadir(30, 30, 10))[1],
                               CAMERA.focal_px / 10, rtol=1e-9)


def test_a_box_stands_on_the_feet_pixel():
    people = on_ground([30.0, 33.0], [30.0, 28.0], None)
    det = SimulatedDetector(grid(model(1.0, 0.0)), people,
                            DetectorOptions(box_noise_px=0.0), 0)
    pose = nadir(30.0, 30.0, 10.0)
    out = det.frame(pose, 0.0)
    assert [d.person_id for d in out] == [0, 1]
    feet = CAMERA.project((people.r_enu_m - pose.r_cam_enu) @ pose.R_enu_cam)
    np.testing.assert_allclose([d.box.bottom_centre_px for d in out], feet, atol=1e-9)
    f = CAMERA.focal_px
    assert out[0].box.width_px == pytest.approx(0.5 * f / 10)
    assert out[0].box.height_px == pytest.approx(0.5 * f / 10)  # from above: as wide
    # 3.6 m off the nadir the head (1.7 m up) projects 3.6 * f * (1 / 8.3 - 1 / 10) px away.
    off = np.hypot(3.0, 2.0)
    assert out[1].box.height_px == pytest.approx(off * f * (1 / 8.3 - 1 / 10), rel=1e-6)
    assert all(0.5 <= d.box.confidence <= 1 for d in out)


def test_detections_and_false_alarms_at_the_models_rates():
    people = place_targets(400, DOMAIN, None, seed=1)
    # 40 false boxes per Mpx: a cell of about 39 px (1,500 px^2) has P_FA about 0.06.
    det = SimulatedDetector(grid(model(0.3, 40.0)), people, DetectorOptions(), 7)
    seen = hits = fa = 0
    expect_fa = var_fa = 0.0
    g = det.grid
    for k in range(60):
        pose = nadir(5.0 + 0.5 * k, 30.0, 12.0, 0.2 * k)
        in_view, _ = det.person_sizes_px(pose)
        out = det.frame(pose, 0.2 * k)
        seen += int(in_view.sum())
        hits += sum(d.person_id >= 0 for d in out)
        fa += sum(d.person_id == FALSE_ALARM_ID for d in out)
        # Each observed cell: the grid's P_FA per look, 1 - exp(-rate A), A = size^2.
        size = g.observe(pose, (0, 40, 0, 40))[1] * det.scale
        p = det.detector.p_false_alarm_per_look(size, size**2)
        expect_fa += p.sum()
        var_fa += (p * (1 - p)).sum()
    # Poisson-binomial counts: within 4 sd of the model's expectation.
    assert abs(hits - 0.3 * seen) < 4 * np.sqrt(seen * 0.3 * 0.7), (hits, seen)
    # A false alarm whose point falls outside the picture (cells at its edge) is dropped.
    assert 0.9 * expect_fa - 4 * np.sqrt(var_fa) < fa < expect_fa + 4 * np.sqrt(var_fa), \
        (fa, expect_fa)


def test_with_a_look_interval_each_person_is_drawn_once_per_interval():
    """Frames 0.2 s apart, interval 1 s: a person's outcome holds for 5 frames."""
    people = Targets(np.array([[30.0, 30.0, 0.0]] * 50))
    det = SimulatedDetector(grid(model(0.5, 0.0)), people,
                            DetectorOptions(look_interval_s=1.0), 2)
    outcomes = np.zeros((20, 50), dtype=bool)
    for k in range(20):
        for d in det.frame(nadir(30.0, 30.0, 10.0), 0.2 * k):
            outcomes[k, d.person_id] = True
    runs = outcomes.reshape(4, 5, 50)
    assert (runs == runs[:, :1]).all()  # the same within each second
    assert 0.3 < outcomes[::5].mean() < 0.7
    assert (outcomes[5::5] != outcomes[0]).any()  # drawn afresh each second


def test_terrain_hides_people_behind_a_ridge():
    from pdcov.core.terrain import TerrainSurface

    g = DOMAIN.grid_geometry(1.0)
    z = np.zeros((g.n_rows + 1, g.n_cols + 1))
    z[:, 33:35] = 8.0  # a wall 8 m high along x = 33..34
    terrain = TerrainSurface(g, z)
    cov = CoverageGrid(g, DOMAIN.free_mask(g), CAMERA, model(1.0, 0.0), terrain=terrain)
    people = on_ground([30.0, 37.5], [30.0, 30.0], terrain)
    det = SimulatedDetector(cov, people, DetectorOptions(), 0)
    in_view, _ = det.person_sizes_px(CameraPose(R_NADIR, np.array([28.0, 30.0, 10.0])))
    assert in_view.tolist() == [True, False]


# Two size bins split at 20 px, four confidence bins of unequal widths; the probability of a
# confidence bin is its density times its width, over the row's sum.
HISTOGRAMS = ConfidenceModel((0.5, 0.6, 0.8, 0.9, 1.0),
                             ((1.0, 2.0, 4.0, 3.0), (5.0, 1.0, 1.0, 1.0)),
                             ((6.0, 1.0, 1.0, 1.0), (1.0, 1.0, 1.0, 6.0)))


@pytest.mark.parametrize("true_positive", [True, False])
def test_confidences_follow_the_models_histograms_by_box_size(true_positive):
    from scipy import stats

    m = DetectorModel((1.0, 20.0, 1000.0), (float(true_positive),) * 2, (0.0, 0.0),
                      (0.0 if true_positive else 120.0,) * 2, input_size_px=640,
                      confidence_threshold=0.5, confidence=HISTOGRAMS)
    det = SimulatedDetector(grid(m), place_targets(400, DOMAIN, None, seed=4),
                            DetectorOptions(), 9)
    size, conf = [], []
    # Boxes of about 30 px and more from 8 m, under 20 px from 25 m (scale 1).
    for k, (x, y, z) in enumerate([(8 + 3 * i, 8 + 3 * j, 8.0) for i in range(9)
                                   for j in range(9)] + [(20.0, 20.0, 25.0)] * 40):
        for d in det.frame(nadir(x, y, z, 0.2 * k), 0.2 * k):
            assert (d.person_id >= 0) == true_positive
            size.append(np.sqrt(d.box.width_px * d.box.height_px) * det.scale)
            conf.append(d.box.confidence)
    size, conf = np.array(size), np.array(conf)
    row = m.nearest_bin(size)
    k = HISTOGRAMS.bin_index(conf)
    p = HISTOGRAMS.probabilities(true_positive)
    for i in (0, 1):
        n = int((row == i).sum())
        assert n > 1000, (i, n)
        observed = np.bincount(k[row == i], minlength=4)
        assert stats.chisquare(observed, n * p[i]).pvalue > 1e-3, (i, observed, n * p[i])
    # Uniform within the drawn bin.
    e = np.asarray(HISTOGRAMS.edges)
    assert stats.kstest((conf - e[k]) / (e[k + 1] - e[k]), "uniform").pvalue > 1e-3
    # The two size bins' histograms differ: a wrong row would fail the chi-square above.
    assert np.abs(p[0] - p[1]).max() > 0.3
