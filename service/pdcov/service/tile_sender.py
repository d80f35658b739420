"""Which of the grid's tiles to send, and when: ``TileSender``.

A tile is ``tile_size`` x ``tile_size`` cells, named (tile row, tile column). Frames mark
the tiles they touched; when tiles are due, the touched ones are compared with the values
last sent, and the changed tiles are encoded oldest change first within the bandwidth
budget: a token bucket of one second at ``max_bytes_per_s`` (bytes/s), the encoded size
learnt from what was sent. Times are the daemon's monotonic clock (s).
"""

from __future__ import annotations

import numpy as np

from pdcov.bus.tiles import encode_tiles, tile_bounds, tile_grid_shape, tile_wire_bytes
from pdcov.core.grid_layer import CellSource, Layer

__all__ = ["TileSender"]


class TileSender:
    """The tiles of ``grid`` (read by window; ``grid_hash`` its hash) sent so far. seq: the
    next tiles message's sequence number. Every tile counts as touched at
    first (a resumed grid's observed tiles are sent)."""

    def __init__(self, grid: CellSource, grid_hash: str, tile_size: int,
                 max_bytes_per_s: float, now_s: float, seq: int = 0) -> None:
        self.grid = grid
        self.grid_hash = grid_hash
        self.tile_size = tile_size
        self.seq = seq
        # Values as last sent, per tile; the tiles frames touched since the last comparison;
        # when each tile first changed unsent.
        self._tile_shape = tile_grid_shape(tile_size, *grid.geometry.shape)
        # Per tile sent, its counts and limiting factors as sent (a tile never sent: 0).
        self._sent: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._touched_tiles = np.ones(self._tile_shape, bool)
        self._dirty_since: dict[tuple[int, int], float] = {}
        self._rate = float(max_bytes_per_s)
        self._allowance = self._rate
        self._ratio = 0.5  # compressed / raw bytes, learnt from what was sent
        self._last_tiles_s = now_s

    @property
    def behind(self) -> int:
        """Changed tiles not yet sent (the bandwidth budget holds them back)."""
        return len(self._dirty_since)

    def touch(self, window: tuple[int, int, int, int]) -> None:
        """Cells rows r0:r1, columns c0:c1 may have changed: their tiles are compared when
        tiles are next due."""
        r0, r1, c0, c1 = window
        ts = self.tile_size
        self._touched_tiles[r0 // ts:(r1 - 1) // ts + 1, c0 // ts:(c1 - 1) // ts + 1] = True

    def send(self, now_s: float, t_s: float) -> bytes | None:
        """The tiles message due at ``now_s``: changed tiles within the bandwidth budget,
        oldest change first, stamped ``t_s`` (the last frame, autopilot clock, s); None when
        nothing is due."""
        rate = self._rate
        self._allowance = min(rate, self._allowance + rate * (now_s - self._last_tiles_s))
        self._last_tiles_s = now_s
        ts = self.tile_size
        grid = self.grid
        # Only tiles frames touched can differ from what was sent (row-major, as the
        # whole-grid comparison this replaces); a frame can change a cell's limiting factor
        # (in view too far, hidden) without a look.
        for tr, tc in zip(*np.nonzero(self._touched_tiles), strict=True):
            key = (int(tr), int(tc))
            if key not in self._dirty_since and self._differs(key):
                self._dirty_since[key] = now_s
        self._touched_tiles[:] = False
        if not self._dirty_since or self._allowance <= 0:
            return None
        order = sorted(self._dirty_since, key=self._dirty_since.__getitem__)
        per_tile = tile_wire_bytes(ts) * self._ratio
        n = max(1, min(len(order), int(self._allowance // max(per_tile, 1.0)), 0xFFFF))
        ids = order[:n]
        payload = encode_tiles(grid, ids, seq=self.seq, t_s=t_s, tile_size=ts,
                               grid_hash=self.grid_hash)
        self.seq += 1
        self._allowance -= len(payload)
        self._ratio = max(0.01, len(payload) / (n * tile_wire_bytes(ts)))
        for key in ids:
            del self._dirty_since[key]
            win = self._window(key)
            self._sent[key] = (grid.read(Layer.N_OBS, win), grid.read(Layer.LIMITING, win))
        return payload

    def _window(self, key: tuple[int, int]) -> tuple[int, int, int, int]:
        g = self.grid.geometry
        return tile_bounds(*key, self.tile_size, g.n_rows, g.n_cols)

    def _differs(self, key: tuple[int, int]) -> bool:
        """Whether tile ``key``'s counts or limiting factors differ from what was sent."""
        win = self._window(key)
        n_obs, limiting = self.grid.read(Layer.N_OBS, win), self.grid.read(Layer.LIMITING, win)
        sent = self._sent.get(key)
        if sent is None:
            return bool(n_obs.any() or limiting.any())
        return bool((n_obs != sent[0]).any() or (limiting != sent[1]).any())
