"""Which of the grid's tiles to send, and when: ``TileSender``.

A tile is ``tile_size`` x ``tile_size`` cells, named (tile row, tile column). Frames mark
the tiles they touched; when tiles are due, the touched ones are compared with the values
last sent (a block at a time, ``bus.tile_blocks``), and the changed tiles are encoded
oldest change first within the bandwidth budget: a token bucket of one second at
``max_bytes_per_s`` (bytes/s), the encoded size learnt from what was sent. Times are the
daemon's monotonic clock (s).
"""

from __future__ import annotations

import numpy as np

from pdcov.bus.tile_blocks import TileBlock, tile_blocks, tiles_in
from pdcov.bus.tiles import encode_tiles, tile_wire_bytes
from pdcov.core.grid_layer import CellSource, Layer
from pdcov.core.tiles import TileKey

__all__ = ["TileSender"]


class TileSender:
    """The tiles of ``grid`` (read by window; ``grid_hash`` its hash) sent so far. seq: the
    next tiles message's sequence number. The tiles the grid holds count as
    touched at first (``CellSource.written_windows``: a resumed grid's are sent)."""

    def __init__(self, grid: CellSource, grid_hash: str, tile_size: int,
                 max_bytes_per_s: float, now_s: float, seq: int = 0) -> None:
        self.grid = grid
        self.grid_hash = grid_hash
        self.tile_size = tile_size
        self.seq = seq
        # Per tile sent, its counts and limiting factors as sent (a tile never sent: 0);
        # the tiles frames touched since the last comparison.
        self._sent: dict[TileKey, tuple[np.ndarray, np.ndarray]] = {}
        self._touched: set[TileKey] = set()
        for window in grid.written_windows():
            self.touch(window)
        # When each changed tile first changed unsent.
        self._dirty_since: dict[TileKey, float] = {}
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
        self._touched.update(tiles_in(window, self.tile_size))

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
        changed: set[TileKey] = set()
        for block in tile_blocks(self._touched - self._dirty_since.keys(), ts, grid.geometry):
            changed.update(self._changed(block))
        for key in sorted(changed):
            self._dirty_since[key] = now_s
        self._touched.clear()
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
        for block in tile_blocks(ids, ts, grid.geometry):
            n_obs = grid.read(Layer.N_OBS, block.window)
            limiting = grid.read(Layer.LIMITING, block.window)
            for key in block.keys:
                del self._dirty_since[key]
                cells = block.cells(key)
                self._sent[key] = (n_obs[cells].copy(), limiting[cells].copy())
        return payload

    def _changed(self, block: TileBlock) -> list[TileKey]:
        """The tiles of ``block`` whose counts or limiting factors differ from what was
        sent."""
        n_obs = self.grid.read(Layer.N_OBS, block.window)
        limiting = self.grid.read(Layer.LIMITING, block.window)
        out = []
        for key in block.keys:
            cells = block.cells(key)
            n, lim = n_obs[cells], limiting[cells]
            sent = self._sent.get(key)
            if (bool(n.any() or lim.any()) if sent is None
                    else bool((n != sent[0]).any() or (lim != sent[1]).any())):
                out.append(key)
        return out
