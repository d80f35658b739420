"""The grid in a chunked store (core/grid_store.py): what is written reads back cell for cell,
changed tiles suffice, a county-sized grid stores what was seen, damaged stores are refused."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest
import zarr

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.free_cells import FreeCells
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_layer import Layer
from pdcov.core.grid_store import (
    frozen_update,
    read_store,
    store_update,
    write_store,
    write_update,
)
from pdcov.core.looks import LooksConfig, LooksRule
from pdcov.core.pose import FixedMount, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx
from pdcov.errors import InputFileError

CAMERA = CameraModel(640, 480, np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]))
DETECTOR = DetectorModel.from_dict({
    "version": 4, "bin_edges_px": [1, 20, 40, 80, 2000], "p_detect": [0.1, 0.4, 0.6, 0.3],
    "p_false_alarm": [0.05, 0.1, 0.2, 0.3], "fa_rate_per_mpx": [20.0, 40.0, 80.0, 120.0],
    "input_size_px": None, "looks": {"correlation": [0.2, 0.2, 0.2, 0.2]}})
# An L-shaped domain with an obstacle, 600 x 560 cells of 1 m: tiles whole, partly free
# and clipped at the grid's edge.
DOMAIN = Domain.from_enu([[-300, -280], [300, -280], [300, 0], [0, 0], [0, 280], [-300, 280]],
                         [[[-100, -100], [-60, -100], [-60, -60], [-100, -60]]])


def grid_of(domain: Domain = DOMAIN, **kw) -> CoverageGrid:
    g = domain.grid_geometry(1.0)
    return CoverageGrid(g, FreeCells(g, free_space=domain.free_space), CAMERA, DETECTOR, **kw)


def fly(grid: CoverageGrid, n: int, seed: int, t0_s: float = 0.0) -> None:
    rng = np.random.default_rng(seed)
    for k in range(n):
        R = R_from_euler_zyx(*np.radians(rng.uniform([-10, -10, 0], [10, 10, 360])))
        xyz = (*rng.uniform(-250, 250, 2), rng.uniform(15, 40))
        grid.update(fixed_mount_pose(R, xyz, FixedMount(pitch_rad=math.radians(-70)),
                                     t0_s + 0.2 * k))


def assert_same(a: CoverageGrid, b: CoverageGrid) -> None:
    assert a.tile_keys() == b.tile_keys()
    for layer in (Layer.LOG_MISS_D, Layer.LOG_MISS_FA, Layer.N_OBS, Layer.LIMITING,
                  Layer.MASK):
        np.testing.assert_array_equal(a.read(layer), b.read(layer), err_msg=layer.value)
    for layer in (Layer.LAST_OBS_S, Layer.LOOKS):
        assert a.keeps(layer) == b.keeps(layer)
        if a.keeps(layer):
            np.testing.assert_array_equal(a.read(layer), b.read(layer), err_msg=layer.value)
    assert (a.frames, a.frames_blurred, a.latest_frame_t_s) == \
        (b.frames, b.frames_blurred, b.latest_frame_t_s)


@pytest.mark.parametrize("kw", [{}, {"min_revisit_s": 0.5},
                                {"looks": LooksConfig(LooksRule.CORRELATED)},
                                {"looks": LooksConfig(LooksRule.VIEWPOINT)}])
def test_a_grid_reads_back_cell_for_cell(tmp_path, kw):
    grid = grid_of(**kw)
    fly(grid, 40, 1)
    assert 1 < len(grid.tile_keys()) < 9  # not every tile was touched
    write_store(tmp_path / "g.zarr", grid)
    back = read_store(tmp_path / "g.zarr", CAMERA, DETECTOR, **kw)
    assert_same(grid, back)
    np.testing.assert_array_equal(back.pd, grid.pd)


def test_changed_tiles_written_after_the_first_write_give_the_whole_grid(tmp_path):
    grid = grid_of(min_revisit_s=0.5)
    fly(grid, 20, 2)
    write_store(tmp_path / "g.zarr", grid)
    before = grid.clock.now
    fly(grid, 20, 3, t0_s=10.0)
    changed = grid.tile_keys(since=before)
    assert 0 < len(changed)
    write_store(tmp_path / "g.zarr", grid, changed)
    assert_same(grid, read_store(tmp_path / "g.zarr", CAMERA, DETECTOR, min_revisit_s=0.5))


def test_the_store_is_a_zarr_v3_group_any_reader_opens(tmp_path):
    grid = grid_of()
    fly(grid, 10, 4)
    write_store(tmp_path / "g.zarr", grid)
    root = zarr.open_group(str(tmp_path / "g.zarr"), mode="r")
    assert root.metadata.zarr_format == 3
    log_miss_d = root["log_miss_d"]
    assert log_miss_d.shape == grid.geometry.shape and log_miss_d.chunks == (256, 256)
    pd = 0.0 - np.expm1(np.asarray(log_miss_d[...], dtype=np.float64))
    np.testing.assert_array_equal(pd, grid.pd)
    assert root.attrs["frames"] == 10 and root.attrs["looks"] == "independent"


def test_a_county_grid_stores_only_what_was_seen(tmp_path):
    # 30 x 30 km at 1 m: 9e8 cells, a few frames in one corner.
    county = Domain.from_enu([[-300, -280], [29_700, -280], [29_700, 29_720],
                              [-300, 29_720]])
    grid = grid_of(county)
    assert grid.geometry.n_rows * grid.geometry.n_cols == 900_000_000
    fly(grid, 10, 5)
    assert grid.nbytes < 20e6  # tiles touched, not the domain (3.6 GB of float32 a layer)
    write_store(tmp_path / "g.zarr", grid)
    on_disk = sum(f.stat().st_size for f in (tmp_path / "g.zarr").rglob("*") if f.is_file())
    assert on_disk < 5e6
    back = read_store(tmp_path / "g.zarr", CAMERA, DETECTOR)
    assert back.tile_keys() == grid.tile_keys()
    for key in grid.tile_keys():
        w = grid.layout.window_of(key)
        np.testing.assert_array_equal(back.read(Layer.LOG_MISS_D, w),
                                      grid.read(Layer.LOG_MISS_D, w))
    assert back.metrics((0.5,)) == grid.metrics((0.5,))


def test_a_store_of_another_grid_is_not_written_over(tmp_path):
    write_store(tmp_path / "g.zarr", grid_of())
    other = Domain.from_enu([[0, 0], [100, 0], [100, 100], [0, 100]])
    with pytest.raises(ValueError, match="a store of another grid"):
        write_store(tmp_path / "g.zarr", grid_of(other))


def test_damaged_stores_are_refused_naming_the_store(tmp_path):
    with pytest.raises(InputFileError, match="missing.zarr: not a usable grid store"):
        read_store(tmp_path / "missing.zarr", CAMERA, DETECTOR)
    grid = grid_of()
    fly(grid, 10, 6)
    path = tmp_path / "g.zarr"
    write_store(path, grid)
    with pytest.raises(InputFileError, match="coverage.looks: independent, the mission says "
                                             "correlated"):
        read_store(path, CAMERA, DETECTOR, looks=LooksConfig(LooksRule.CORRELATED))
    root = zarr.open_group(str(path), mode="a")
    key = grid.tile_keys()[0]
    r0, _, c0, _ = grid.layout.window_of(key)
    root["log_miss_d"][r0, c0] = np.nan
    with pytest.raises(InputFileError, match=r"g.zarr: not a usable grid snapshot: "
                                             r"log_miss_d: NaN"):
        read_store(path, CAMERA, DETECTOR)
    root["log_miss_d"][r0, c0] = 0.0
    root.attrs["frames"] = -3
    with pytest.raises(InputFileError, match="frames: expected a count, got -3"):
        read_store(path, CAMERA, DETECTOR)
    root.attrs["pdcov_grid"] = 99
    with pytest.raises(InputFileError, match="not a pdcov grid store of version 1"):
        read_store(path, CAMERA, DETECTOR)


@pytest.mark.parametrize("threaded", [False, True])
@pytest.mark.parametrize("kw", [{"min_revisit_s": 0.5},
                                {"looks": LooksConfig(LooksRule.CORRELATED)}])
def test_a_frozen_update_written_while_the_grid_goes_on_is_the_grid_when_frozen(
        tmp_path, kw, threaded):
    # The daemon's checkpoint: taken on the loop (nothing copied), written by a thread
    # while frames keep coming; the store holds the grid as it was when taken. Without a
    # thread every tile is written by the grid first (copied then), with one in any order.
    grid = grid_of(**kw)
    fly(grid, 30, 7)
    then = store_update(grid)  # copied at once: the reference
    frozen = frozen_update(grid)
    writer = threading.Thread(target=write_update, args=(tmp_path / "g.zarr", frozen))
    if threaded:
        writer.start()
    fly(grid, 30, 7, t0_s=20.0)  # the same tiles written again, meanwhile
    if not threaded:
        writer.start()
    writer.join()
    frozen.release()
    write_update(tmp_path / "ref.zarr", then)
    assert_same(read_store(tmp_path / "g.zarr", CAMERA, DETECTOR, **kw),
                read_store(tmp_path / "ref.zarr", CAMERA, DETECTOR, **kw))
    assert grid.frames == 60  # the grid went on: 30 frames after the freeze
    with pytest.raises(RuntimeError, match="frozen for another reader"):
        frozen_update(grid), frozen_update(grid)
