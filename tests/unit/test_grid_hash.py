"""The grid hashes (the bus's ``grid_hash``, a checkpoint's ``mission_hash``) are computed
band by band of rows (``FreeCells.packed_rows``) and give the digits of the whole mask's
``np.packbits``: on an L-shaped domain with an obstacle, tiles the boundary crosses and a
ragged last band."""

from __future__ import annotations

import hashlib
import struct

import numpy as np

from pdcov.bus.grid_state import GridState, grid_hash
from pdcov.config.load import mission_from_dict
from pdcov.core.domain import Domain
from pdcov.core.free_cells import FreeCells
from pdcov.service.settings import mission_hash
from tests.support.harness import small_mission

# 300 x 301 cells of 1 m: two bands of rows (256 + a ragged 44), two tile columns.
L_SHAPE = [[0, 0], [301, 0], [301, 120], [130, 120], [130, 300], [0, 300]]
OBSTACLE = [[40.5, 200.2], [90.3, 200.2], [90.3, 260.7], [40.5, 260.7]]


def dense_grid_hash(geometry, mask: np.ndarray) -> str:
    """The hash as computed before the bands: the whole mask packed at once."""
    head = struct.pack("<dddII", geometry.x0_m, geometry.y0_m, geometry.cell_size_m,
                       geometry.n_rows, geometry.n_cols)
    return hashlib.sha256(head + np.packbits(mask.ravel()).tobytes()).hexdigest()[:16]


def l_domain() -> Domain:
    return Domain.from_enu(L_SHAPE, [OBSTACLE])


def test_packed_rows_concatenate_to_the_whole_mask_packed():
    d = l_domain()
    g = d.grid_geometry(1.0)
    assert g.shape == (300, 301)
    dense = d.free_mask(g)
    for free in (FreeCells(g, free_space=d.free_space), FreeCells(g, mask=dense)):
        bands = list(free.packed_rows())
        assert len(bands) == 2
        assert np.array_equal(np.concatenate(bands), np.packbits(dense))


def test_grid_hash_equals_the_dense_computation():
    d = l_domain()
    g = d.grid_geometry(1.0)
    dense = d.free_mask(g)
    want = dense_grid_hash(g, dense)
    assert grid_hash(g, FreeCells(g, free_space=d.free_space)) == want
    assert grid_hash(g, dense) == want
    assert GridState.empty(g, dense).hash == want


def test_mission_hash_equals_the_dense_computation(tmp_path, monkeypatch):
    doc = small_mission(domain={"polygon_enu_m": L_SHAPE, "obstacles_enu_m": [OBSTACLE],
                                "cell_size_m": 1.0})
    m = mission_from_dict(doc, source="m.yaml", base_dir=tmp_path)
    grid = m.new_mission_grid()
    streamed = mission_hash(m, grid)
    dense = np.packbits(m.domain.free_mask(grid.geometry))
    monkeypatch.setattr(grid.free, "packed_rows", lambda: iter([dense]))  # the whole mask
    assert mission_hash(m, grid) == streamed
