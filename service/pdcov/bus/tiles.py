"""The tiles payload (``pdcov/<id>/tiles``): the grid's changed tiles, exactly.

The grid is cut into square tiles of ``tile_size`` cells (the last row and column of tiles
may be smaller). A message carries whole tiles with their current values (not increments),
so applying a tile twice, or an older tile after a newer one of the same message sequence,
cannot drift; a subscriber that notices a gap in ``seq`` fetches the snapshot.

Layout (little-endian; docs/protocol.md "tiles"): a 48-byte header

    magic b"PDTL" | version u16 | flags u16 (0) | seq u64 | grid hash 8 bytes (the 16 hex
    digits of grid_state.grid_hash) | t_s f64 | frames u32 | tile_size u16 | n_tiles u16 |
    n_rows u32 | n_cols u32

then a zlib stream of n_tiles records: tile_row u16, tile_col u16, then for the tile's
h x w cells in row-major order log_miss_d float32[h*w], log_miss_fa float32[h*w],
n_obs uint32[h*w], pd_q uint16[h*w] (P_D quantised as round(P_D * 65535), for display)
and, from version 2, limiting uint8[h*w] (LimitingFactor codes). The daemon sends version
2; version 1 (older daemons) still decodes, its tiles' limiting None (unknown).
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from pdcov.bus.errors import BusPayloadError, Refusal, Refuser
from pdcov.bus.grid_state import GridState, check_values
from pdcov.bus.grid_state import grid_hash as hash_of_grid
from pdcov.bus.tile_blocks import tile_blocks
from pdcov.core.domain import MAX_GRID_CELLS
from pdcov.core.grid_layer import CellSource, Layer

MAGIC = b"PDTL"
TILES_VERSION = 2
READABLE_TILES_VERSIONS = (1, 2)
_HEADER = struct.Struct("<4sHHQ8sdIHHII")
_TILE_ID = struct.Struct("<HH")
_CELL_DTYPES = {1: ("<f4", "<f4", "<u4", "<u2"), 2: ("<f4", "<f4", "<u4", "<u2", "u1")}
"""Per version, the dtypes of a record's per-cell arrays, in order."""
BYTES_PER_CELL = {v: sum(np.dtype(d).itemsize for d in ds) for v, ds in _CELL_DTYPES.items()}
MAX_TILE_SIZE = 1024
MAX_BODY_BYTES = 64 << 20
"""Largest inflated tiles body a decoder accepts (the daemon sends far less per message)."""
MAX_TILES_BYTES = 4 << 20
"""Largest tiles payload accepted (the daemon sends at most bus.tiles_max_bytes_per_s,
64 KiB by default, per second)."""


@dataclass(frozen=True, slots=True)
class Tile:
    """One tile's cells: its (tile_row, tile_col) and (h, w) arrays as the grid holds them;
    limiting None from a version-1 message (unknown)."""

    tile_row: int
    tile_col: int
    log_miss_d: np.ndarray
    log_miss_fa: np.ndarray
    n_obs: np.ndarray
    pd_q: np.ndarray
    limiting: np.ndarray | None


@dataclass(frozen=True, slots=True)
class TileUpdate:
    """A decoded tiles message. t_s: autopilot time (s) of the newest frame in it; frames:
    the daemon's frame count then; version: the message's layout (1: no limiting)."""

    version: int
    seq: int
    grid_hash: str
    t_s: float
    frames: int
    tile_size: int
    n_rows: int
    n_cols: int
    tiles: tuple[Tile, ...]


def tile_bounds(tile_row: int, tile_col: int, tile_size: int, n_rows: int, n_cols: int
                ) -> tuple[int, int, int, int]:
    """(r0, r1, c0, c1): the cells of a tile, clipped to the grid."""
    r0, c0 = tile_row * tile_size, tile_col * tile_size
    return r0, min(r0 + tile_size, n_rows), c0, min(c0 + tile_size, n_cols)


def tile_grid_shape(tile_size: int, n_rows: int, n_cols: int) -> tuple[int, int]:
    """How many tile rows and columns cover an n_rows x n_cols grid."""
    return -(-n_rows // tile_size), -(-n_cols // tile_size)


def tile_wire_bytes(tile_size: int, version: int = TILES_VERSION) -> int:
    """Uncompressed bytes of one full tile record (the compressed size is less)."""
    return _TILE_ID.size + BYTES_PER_CELL[version] * tile_size * tile_size


def encode_tiles(source: CellSource, tiles: Iterable[tuple[int, int]], *, seq: int,
                 t_s: float, tile_size: int, level: int = 6,
                 grid_hash: str | None = None) -> bytes:
    """The tiles message carrying the current values of ``tiles`` ((tile_row, tile_col))
    of ``source`` (the daemon's grid, or a GridState, whose limiting factors must be
    known). ``grid_hash``: the source's (``grid_state.grid_hash``) when the caller keeps
    it (it reads the whole mask); the cost otherwise follows the tiles sent, not the
    grid."""
    g = source.geometry
    ids = list(dict.fromkeys((int(r), int(c)) for r, c in tiles))
    if not 1 <= tile_size <= MAX_TILE_SIZE:
        raise ValueError(f"tile_size {tile_size}: expected 1..{MAX_TILE_SIZE}")
    if len(ids) > 0xFFFF:
        raise ValueError(f"{len(ids)} tiles in one message; at most 65535")
    for tr, tc in ids:
        r0, r1, c0, c1 = tile_bounds(tr, tc, tile_size, g.n_rows, g.n_cols)
        if r0 >= r1 or c0 >= c1:
            raise ValueError(f"tile ({tr}, {tc}) lies outside the grid")
    encoded: dict[tuple[int, int], list[bytes]] = {}
    for block in tile_blocks(ids, tile_size, g):  # each layer read once per block
        win = block.window
        log_miss_d = source.read(Layer.LOG_MISS_D, win)
        pd = 0.0 - np.expm1(log_miss_d.astype(np.float64))  # Layer.PD's values
        layers = (log_miss_d.astype("<f4"), source.read(Layer.LOG_MISS_FA, win).astype("<f4"),
                  source.read(Layer.N_OBS, win).astype("<u4"),
                  np.rint(pd * 65535.0).astype("<u2"),
                  source.read(Layer.LIMITING, win).astype("u1"))
        for key in block.keys:
            cells = block.cells(key)
            encoded[key] = [_TILE_ID.pack(*key), *(a[cells].tobytes() for a in layers)]
    parts = [b for key in ids for b in encoded[key]]
    header = _HEADER.pack(MAGIC, TILES_VERSION, 0, seq, bytes.fromhex(
        grid_hash or hash_of_grid(g, source.read(Layer.MASK))),
                          float(t_s), min(source.frames, 0xFFFFFFFF), tile_size, len(ids),
                          g.n_rows, g.n_cols)
    return header + zlib.compress(b"".join(parts), level)


def decode_tiles(payload: bytes, key: str = "tiles",
                 max_body_bytes: int = MAX_BODY_BYTES) -> TileUpdate:
    """Validate and decode a tiles message: at most MAX_TILES_BYTES, magic, version, a t_s
    not NaN nor +inf, header sizes, a grid of at most MAX_GRID_CELLS (checked before inflating),
    tile indices inside the grid and not repeated, the exact body length (the inflated size
    is capped before inflating: no zlib bomb), log-miss sums <= 0 and not NaN, counts and
    (version 2) limiting codes in range. Version 1 decodes with limiting None. Raises
    BusPayloadError naming ``key`` (its ``reason`` says why)."""
    bad = Refuser(f"{key}: not a usable tiles message")
    data = bytes(payload)
    if len(data) > MAX_TILES_BYTES:
        raise bad(f"{len(data)} bytes, more than {MAX_TILES_BYTES}", Refusal.TOO_LARGE)
    if len(data) < _HEADER.size:
        raise bad(f"{len(data)} bytes, shorter than the {_HEADER.size}-byte header",
                  Refusal.MALFORMED)
    (magic, version, _flags, seq, ghash, t_s, frames, tile_size, n_tiles, n_rows,
     n_cols) = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise bad(f"magic {magic!r}, expected {MAGIC!r}", Refusal.MALFORMED)
    if version not in READABLE_TILES_VERSIONS:
        raise bad(f"version {version}, expected "
                  f"{' or '.join(map(str, READABLE_TILES_VERSIONS))}", Refusal.MALFORMED)
    cell_bytes, dtypes = BYTES_PER_CELL[version], _CELL_DTYPES[version]
    if math.isnan(t_s) or t_s == math.inf:  # -inf: no frame yet (the daemon's start value)
        raise bad(f"t_s {t_s}: expected a time (s)", Refusal.NON_FINITE)
    if not 1 <= tile_size <= MAX_TILE_SIZE or n_rows < 1 or n_cols < 1:
        raise bad(f"tile_size {tile_size}, grid {n_rows} x {n_cols}: expected tile_size "
                  f"1..{MAX_TILE_SIZE} and at least one row and column")
    if n_rows * n_cols > MAX_GRID_CELLS:
        raise bad(f"grid {n_rows} x {n_cols}: more than MAX_GRID_CELLS {MAX_GRID_CELLS} "
                  "cells", Refusal.OVER_BOUND)
    n_tr, n_tc = tile_grid_shape(tile_size, n_rows, n_cols)
    if n_tiles > n_tr * n_tc:
        raise bad(f"{n_tiles} tiles, the grid has {n_tr * n_tc}", Refusal.OVER_BOUND)
    bound = min(n_tiles * tile_wire_bytes(tile_size, version),
                n_tiles * _TILE_ID.size + cell_bytes * n_rows * n_cols, max_body_bytes)
    d = zlib.decompressobj()
    try:
        body = d.decompress(data[_HEADER.size:], bound + 1)
    except zlib.error as exc:
        raise bad(f"zlib: {exc}", Refusal.MALFORMED) from None
    if len(body) > bound or not d.eof or d.unused_data:
        raise bad("the zlib body is longer than its tiles, incomplete, or followed by bytes",
                  Refusal.MALFORMED)
    tiles = []
    seen = set()
    at = 0
    for _ in range(n_tiles):
        if at + _TILE_ID.size > len(body):
            raise bad("body ends inside a tile record")
        tr, tc = _TILE_ID.unpack_from(body, at)
        if tr >= n_tr or tc >= n_tc:
            raise bad(f"tile ({tr}, {tc}) outside the {n_tr} x {n_tc} tiles of the grid")
        if (tr, tc) in seen:
            raise bad(f"tile ({tr}, {tc}) appears twice")
        seen.add((tr, tc))
        r0, r1, c0, c1 = tile_bounds(tr, tc, tile_size, n_rows, n_cols)
        shape = (r1 - r0, c1 - c0)
        n = shape[0] * shape[1]
        at += _TILE_ID.size
        if at + cell_bytes * n > len(body):
            raise bad("body ends inside a tile record")
        arrays = []
        for dtype in dtypes:
            a = np.frombuffer(body, dtype=dtype, count=n, offset=at)
            arrays.append(a.reshape(shape).astype(dtype.lstrip("<")))
            at += a.nbytes
        tiles.append(Tile(tr, tc, arrays[0], arrays[1], arrays[2].astype(np.int64), arrays[3],
                          arrays[4] if version >= 2 else None))
    if at != len(body):
        raise bad(f"{len(body) - at} bytes after the last tile")
    for t in tiles:
        check_values(t.log_miss_d, t.log_miss_fa, t.n_obs, bad, t.limiting)
    return TileUpdate(version, seq, ghash.hex(), t_s, frames, tile_size, n_rows, n_cols,
                      tuple(tiles))


def apply_tiles(state: GridState, update: TileUpdate, key: str = "tiles", *,
                state_hash: str | None = None) -> None:
    """Write the update's tiles into ``state``; checks first that it is meant for this grid
    (hash and shape), so that a mismatched update changes nothing (BusPayloadError).
    ``state_hash``: the state's hash when the caller keeps it (it reads the whole mask). A
    version-1 update leaves the state's limiting unknown (None): the cells it rewrites may
    have changed their limiting factor."""
    g = state.geometry
    mine = state_hash or state.hash
    if update.grid_hash != mine or (update.n_rows, update.n_cols) != g.shape:
        raise BusPayloadError(f"{key}: tiles for grid {update.grid_hash} "
                              f"({update.n_rows} x {update.n_cols}), this grid is {mine} "
                              f"({g.n_rows} x {g.n_cols}); fetch the snapshot",
                              Refusal.OTHER_GRID)
    for t in update.tiles:
        window = tile_bounds(t.tile_row, t.tile_col, update.tile_size, *g.shape)
        state.write(Layer.LOG_MISS_D, window, t.log_miss_d)
        state.write(Layer.LOG_MISS_FA, window, t.log_miss_fa)
        state.write(Layer.N_OBS, window, t.n_obs)
        if state.limiting_known and t.limiting is not None:
            state.write(Layer.LIMITING, window, t.limiting)
    if update.version < 2:
        state.forget_limiting()
    state.frames = update.frames
