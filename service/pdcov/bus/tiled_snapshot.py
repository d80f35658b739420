"""The snapshot of a grid larger than a grid.npz snapshot carries (``.../snapshot`` of a grid
over ``grid_state.MAX_CELLS`` cells): its free space and the tiles it wrote, so that a watcher
joining late holds a county's grid in the memory of the cells seen (docs/protocol.md
"Snapshot of a large grid").

Layout (little-endian): a 64-byte header

    magic b"PDSS" | version u16 | flags u16 (1: limiting factors known) | grid hash 8 bytes |
    x0_m f64 | y0_m f64 | cell_size_m f64 | n_rows u32 | n_cols u32 | frames u32 |
    free_space_bytes u32 | n_parts u32 | reserved u32 (0)

then the grid's free space (ENU metres) as WKB of a Polygon or MultiPolygon, then
``n_parts`` tiles messages (``bus/tiles.py``, each preceded by its length, u32) holding every
tile the grid wrote. The free cells are rebuilt from the free space tile by tile (as the
daemon's grid finds them) and must give the grid hash, which covers them: a free space that
does not is refused.
"""

from __future__ import annotations

import struct

import shapely
from shapely.geometry import MultiPolygon, Polygon

from pdcov.bus.errors import BusPayloadError, Refusal, Refuser
from pdcov.bus.grid_state import (
    MAX_CELLS,
    MAX_ENU_M,
    MAX_SNAPSHOT_BYTES,
    GridState,
    decode_snapshot,
    encode_snapshot,
    grid_hash,
)
from pdcov.bus.tile_blocks import tiles_in
from pdcov.bus.tiles import (
    MAX_TILES_BYTES,
    apply_tiles,
    decode_tiles,
    encode_tiles,
    tile_wire_bytes,
)
from pdcov.core.domain import MAX_GRID_CELLS, GridGeometry
from pdcov.core.free_cells import FreeCells
from pdcov.core.grid import CoverageGrid
from pdcov.errors import DomainError

MAGIC = b"PDSS"
VERSION = 1
_HEADER = struct.Struct("<4sHH8sdddIIIIII")
_LENGTH = struct.Struct("<I")
_LIMITING_KNOWN = 1
MAX_FREE_SPACE_BYTES = 4 << 20
"""Largest free space accepted (WKB; about 250,000 vertices)."""


def encode_grid_snapshot(grid: CoverageGrid, tile_size: int, hash_of_grid: str) -> bytes:
    """The snapshot reply of ``grid``: its grid.npz bytes up to MAX_CELLS cells (what every
    pdcov watch reads), tiled above (``encode_tiled_snapshot``)."""
    g = grid.geometry
    if g.n_rows * g.n_cols <= MAX_CELLS:
        return encode_snapshot(grid)
    return encode_tiled_snapshot(grid, tile_size, hash_of_grid)


def decode_grid_snapshot(payload: bytes, key: str = "snapshot") -> GridState:
    """A snapshot reply of either layout, validated (``decode_tiled_snapshot``,
    ``grid_state.decode_snapshot``)."""
    if bytes(payload[:4]) == MAGIC:
        return decode_tiled_snapshot(payload, key)
    return decode_snapshot(payload, key)


def encode_tiled_snapshot(grid: CoverageGrid, tile_size: int, hash_of_grid: str) -> bytes:
    """The snapshot of ``grid`` (its free cells found from a free space) in tiles messages
    of ``tile_size`` cells a side; ``hash_of_grid``: its ``grid_state.grid_hash``."""
    free = grid.free.free_space
    if free is None:
        raise ValueError("a tiled snapshot needs the grid's free space (a mask was given)")
    keys = sorted({k for w in grid.written_windows() for k in tiles_in(w, tile_size)})
    # As many tiles a message as keep it under MAX_TILES_BYTES uncompressed.
    per_part = max(1, min(0xFFFF, MAX_TILES_BYTES // tile_wire_bytes(tile_size)))
    parts = [encode_tiles(grid, keys[i:i + per_part], seq=0, t_s=0.0, tile_size=tile_size,
                          grid_hash=hash_of_grid)  # seq, t_s unused: the header has the frames
             for i in range(0, len(keys), per_part)]
    wkb = shapely.to_wkb(free)
    g = grid.geometry
    header = _HEADER.pack(MAGIC, VERSION, _LIMITING_KNOWN, bytes.fromhex(hash_of_grid),
                          g.x0_m, g.y0_m, g.cell_size_m, g.n_rows, g.n_cols,
                          min(grid.frames, 0xFFFFFFFF), len(wkb), len(parts), 0)
    return b"".join([header, wkb, *(_LENGTH.pack(len(p)) + p for p in parts)])


def decode_tiled_snapshot(payload: bytes, key: str = "snapshot") -> GridState:
    """Validate a tiled snapshot and return its GridState. Checks: at most
    MAX_SNAPSHOT_BYTES, magic and version, a grid of at most MAX_GRID_CELLS cells at finite
    ENU coordinates within MAX_ENU_M, a free space of at most MAX_FREE_SPACE_BYTES that is a
    valid Polygon or MultiPolygon and gives the grid hash, the parts' lengths exactly
    filling the payload, each part a valid tiles message (decode_tiles) of this grid.
    Raises BusPayloadError naming ``key`` (its ``reason`` says why)."""
    bad = Refuser(f"{key}: not a usable grid snapshot")
    data = bytes(payload)
    if len(data) > MAX_SNAPSHOT_BYTES:
        raise bad(f"{len(data)} bytes, more than {MAX_SNAPSHOT_BYTES}", Refusal.TOO_LARGE)
    if len(data) < _HEADER.size:
        raise bad(f"{len(data)} bytes, shorter than the {_HEADER.size}-byte header",
                  Refusal.MALFORMED)
    (magic, version, flags, ghash, x0_m, y0_m, cell_size_m, n_rows, n_cols, frames,
     n_wkb, n_parts, _reserved) = _HEADER.unpack_from(data)
    if magic != MAGIC or version != VERSION:
        raise bad(f"magic {magic!r} version {version}, expected {MAGIC!r} {VERSION}",
                  Refusal.MALFORMED)
    if not (abs(x0_m) <= MAX_ENU_M and abs(y0_m) <= MAX_ENU_M):
        raise bad(f"x0_m, y0_m: expected metres within {MAX_ENU_M:g}")
    if n_rows * n_cols > MAX_GRID_CELLS:
        raise bad(f"grid {n_rows} x {n_cols}: more than {MAX_GRID_CELLS} cells",
                  Refusal.OVER_BOUND)
    try:
        geometry = GridGeometry(x0_m, y0_m, cell_size_m, n_rows, n_cols)
    except DomainError as exc:
        raise bad(f"grid: {exc}") from None
    if n_wkb > MAX_FREE_SPACE_BYTES or _HEADER.size + n_wkb > len(data):
        raise bad(f"free space of {n_wkb} bytes: more than {MAX_FREE_SPACE_BYTES} or than "
                  "the payload holds", Refusal.OVER_BOUND)
    free_space = _free_space(data[_HEADER.size:_HEADER.size + n_wkb], bad)
    free = FreeCells(geometry, free_space=free_space)
    if grid_hash(geometry, free) != ghash.hex():
        raise bad(f"the free space does not give the grid hash {ghash.hex()}")
    state = GridState(geometry, free, limiting_known=bool(flags & _LIMITING_KNOWN))
    at = _HEADER.size + n_wkb
    for i in range(n_parts):
        if at + _LENGTH.size > len(data):
            raise bad(f"part {i}: the payload ends before it", Refusal.MALFORMED)
        (n,) = _LENGTH.unpack_from(data, at)
        at += _LENGTH.size
        if at + n > len(data):
            raise bad(f"part {i}: {n} bytes, the payload ends before", Refusal.MALFORMED)
        try:
            apply_tiles(state, decode_tiles(data[at:at + n], f"{key} part {i}"),
                        f"{key} part {i}", state_hash=ghash.hex())
        except BusPayloadError as exc:
            raise bad(str(exc), exc.reason) from None
        at += n
    if at != len(data):
        raise bad(f"{len(data) - at} bytes after the last part", Refusal.MALFORMED)
    state.frames = int(frames)
    return state


def _free_space(wkb: bytes, bad: Refuser) -> Polygon | MultiPolygon:
    """The free space of its WKB: a valid, non-empty Polygon or MultiPolygon."""
    try:
        shape = shapely.from_wkb(wkb)
    except (shapely.errors.GEOSException, ValueError, TypeError) as exc:
        raise bad(f"free space: not WKB ({exc})"[:300], Refusal.MALFORMED) from None
    if not isinstance(shape, (Polygon, MultiPolygon)) or shape.is_empty \
            or not shape.is_valid:
        raise bad(f"free space: expected a valid Polygon or MultiPolygon, got "
                  f"{shape.geom_type}{' (invalid)' if not shape.is_valid else ''}")
    return shape
