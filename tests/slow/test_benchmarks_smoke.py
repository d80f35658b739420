"""The benchmarks at their tiny CI size: every step runs, and the reference grids agree with
pdcov's within the tolerances the benchmark states. No timing is asserted."""

import numpy as np
import pytest

from benchmarks.__main__ import (
    R1_MIN_SHARE,
    R1_TOLERANCE_PD,
    R2_MIN_SHARE,
    R2_TOLERANCE_PD,
    compare_reference,
)
from benchmarks.measure import terrain_agreement, time_updates
from benchmarks.report import END_MARKER, START_MARKER, write_readme_block
from benchmarks.scenarios import scenarios, spaced
from benchmarks.terrain import R3_TOLERANCE_PD, TerrainSite
from pdcov.core.camera import CameraModel
from tests.support.references import pixel_rays


@pytest.mark.parametrize("name", ["S1", "S3", "S4"])
def test_references_agree_with_pdcov(name):
    sc = scenarios(smoke=True)[name]
    frames = spaced(sc.poses(), 4, max(1, round(sc.rate_hz * 0.5)))
    rays = pixel_rays(sc.camera)
    _, _, r1, _ = compare_reference(sc, frames, "R1", rays, R1_TOLERANCE_PD)
    _, _, r2, skipped = compare_reference(sc, frames, "R2", rays, R2_TOLERANCE_PD)
    assert r1.cells_compared > 100 and r2.cells_compared > 100
    assert r2.looks_differ == 0 and skipped == 0
    assert r2.share_within >= R2_MIN_SHARE
    if name == "S1":  # the target's scenario; elsewhere R1's pixel counting is coarser
        assert r1.share_within >= R1_MIN_SHARE


def test_terrain_reference_agrees_with_pdcov(tmp_path):
    # S5 at its smoke size, 4 frames, R3 through every pixel. Its 480x270 camera makes a
    # 1 m cell ~6 px wide, 8 detector-input px, at a bin edge that R3's counting of pixel
    # centres moves cells across (R1 meets its target at this size only on S1): the smoke
    # check is that the DEM brings pdcov from flat's ~40 % to R3's answer on most cells,
    # and that it never counts ground no ray reached.
    sc = scenarios(smoke=True)["S5"]
    site = TerrainSite.prepare(tmp_path, sc)
    frames = spaced(sc.poses(), 4, max(1, round(sc.rate_hz * 0.5)))
    grid, flat = site.terrain_grid(), sc.new_grid()
    time_updates(grid, frames)
    time_updates(flat, frames)
    ref, _ = site.run_reference(grid, frames)
    a = terrain_agreement(grid, ref, R3_TOLERANCE_PD)
    f = terrain_agreement(flat, ref, R3_TOLERANCE_PD)
    assert a.cells_observed > 1500
    assert a.never_seen_counted == 0 and a.hidden_counted == 0
    assert f.never_seen_counted > 500
    assert a.share_within_observed >= 0.85 and f.share_within_observed <= 0.6


def test_lattice_projection_matches_opencv_project_points():
    # The grid's fast path (initUndistortRectifyMap) against projectPoints, point by point.
    H = np.array([[1.0, 0.1, -40.0], [0.05, -0.9, 20.0], [0.02, 0.3, 60.0]])
    jj, ii = np.meshgrid(np.arange(61), np.arange(41))
    p_cam = np.stack([jj, ii, np.ones_like(jj)], axis=-1) @ H.T
    for cam in (CameraModel.from_fov(1920, 1080, 80, "plumb_bob", (-0.05, 0.01, 5e-4, -5e-4, 0)),
                CameraModel.from_fov(1920, 1080, 150, "fisheye", (0.01, -0.005, 0.001, 0.0)),
                CameraModel.from_fov(640, 480, 70)):
        px = cam.project_lattice(H, 61, 41)
        np.testing.assert_allclose(px.reshape(-1, 2), cam.project(p_cam.reshape(-1, 3)),
                                   atol=2e-4 if cam.dist_coeffs.any() or cam.is_fisheye
                                   else 1e-9)


def test_readme_block_is_replaced_between_markers_only(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("# title\n\ntext\n")
    write_readme_block(readme, "table 1")
    write_readme_block(readme, "table 2")
    text = readme.read_text()
    assert text.startswith("# title\n\ntext\n\n" + START_MARKER)
    assert "table 2" in text and "table 1" not in text and text.count(END_MARKER) == 1
