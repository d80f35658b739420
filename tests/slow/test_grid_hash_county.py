"""A county's grid hash (30 x 30 km at 1 m, 9 x 10^8 cells) is computed band by band: far
less memory than its 900 MB mask, and the digits of the dense computation's bands."""

from __future__ import annotations

import hashlib
import struct
import tracemalloc

import numpy as np

from pdcov.bus.grid_state import grid_hash
from pdcov.core.domain import Domain
from pdcov.core.free_cells import FreeCells

SIDE_M = 30_000


def test_a_county_is_hashed_without_its_whole_mask():
    d = Domain.from_enu([[0, 0], [SIDE_M, 0], [SIDE_M, SIDE_M], [0, SIDE_M]])
    g = d.grid_geometry(1.0)
    assert g.n_rows * g.n_cols == 900_000_000
    free = FreeCells(g, free_space=d.free_space)
    tracemalloc.start()
    try:
        got = grid_hash(g, free)
        peak_b = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak_b < 100e6  # the dense mask: 900 MB
    # Every cell free: the mask packs to bytes of 0xFF.
    head = struct.pack("<dddII", 0.0, 0.0, 1.0, SIDE_M, SIDE_M)
    h = hashlib.sha256(head)
    row_band = np.full(256 * SIDE_M // 8, 0xFF, np.uint8).tobytes()
    for r0 in range(0, SIDE_M, 256):
        h.update(row_band[:min(256, SIDE_M - r0) * SIDE_M // 8])
    assert got == h.hexdigest()[:16]
