"""A coverage grid in a chunked store on disk (Zarr v3): one chunk per tile and layer.

For grids that do not fit one file or memory, and for checkpoints that write only the tiles
changed since the last (``write_store(..., keys=...)``). Each stored layer is an array of
the grid's shape in chunks of the grid's tiles (``tiles.TILE_CELLS``), compressed with
Blosc/zstd and checksummed (CRC32C: a damaged chunk is refused, never read as other
values): log_miss_d, log_miss_fa (float32, <= 0), n_obs (int32), limiting (uint8), with
``min_revisit_s`` last_obs_s (s, float64), and with correlated or viewpoint looks
looks_counts or looks_best ((rows, cols, K)). A chunk never written reads as its fill value
(0, or -inf for the clock): a tile no frame touched. ``tiles`` (uint8, one cell per tile)
marks the tiles written. The group's attributes: ``pdcov_grid`` (the store's version),
the geometry (x0_m, y0_m: ENU south-west corner of cell [0, 0]; cell_size_m, n_rows,
n_cols), tile_cells, frames, frames_blurred, looks (the rule), latest_frame_t_s, and the
free cells: ``free_space_wkb`` (the domain's free space, ENU metres, hex WKB) or, for a
grid made from a mask array, a ``mask`` array.

Any Zarr v3 reader opens it (zarr-python, xarray, tensorstore). Each chunk is written
atomically (a temporary file renamed), but a store being written holds old and new tiles
side by side: a checkpoint keeps two stores and names the complete one
(service/checkpoint.py).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
import zarr
from zarr.codecs import BloscCodec, Crc32cCodec

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.free_cells import FreeCells
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_layer import Layer
from pdcov.core.grid_snapshot import check_snapshot_values
from pdcov.core.looks import LooksConfig, LooksRule, ViewpointLooks
from pdcov.core.terrain import TerrainSurface
from pdcov.core.tiles import FrozenTiles, TiledLayer, TileKey, TileLayout
from pdcov.errors import InputFileError
from pdcov.npz_file import DAMAGED

STORE_VERSION = 1
# What reading a damaged store raises: a file's errors (npz_file.DAMAGED: JSON, shapes,
# memory), and a chunk's codecs' (Blosc and zstd raise RuntimeError, a negative size
# SystemError).
_DAMAGED_STORE = (*DAMAGED, RuntimeError, SystemError)
# Blosc alone may decode a damaged chunk into other valid values: the CRC32C refuses it.
_COMPRESSORS = (BloscCodec(cname="zstd", clevel=3, shuffle="bitshuffle"), Crc32cCodec())
_STORED = (Layer.LOG_MISS_D, Layer.LOG_MISS_FA, Layer.N_OBS, Layer.LIMITING,
           Layer.LAST_OBS_S, Layer.LOOKS)
_TILES = "tiles"


def _array(root: zarr.Group, name: str) -> zarr.Array:
    """The array ``name`` of the store (KeyError: none)."""
    found = root[name]
    if not isinstance(found, zarr.Array):
        raise KeyError(f"{name} is not an array")
    return found


def _array_name(grid_looks: LooksRule, layer: Layer) -> str:
    if layer is Layer.LOOKS:
        return "looks_counts" if grid_looks is LooksRule.CORRELATED else "looks_best"
    return layer.value


@dataclass(frozen=True, slots=True, eq=False)
class StoreUpdate:
    """What ``write_update`` writes into a store, of a grid at one moment, so that the grid
    may go on while it is written: ``tiles`` per stored layer, tile key -> its array as it
    was (copied at once, ``store_update``, or when first needed, ``frozen_update``);
    ``layers``: each stored layer's (dtype, fill, depth); ``attrs``: the group's
    attributes; ``mask``: the free cells of a grid made from a mask array, else None;
    ``frozen``: the copy-on-write tiles of a ``frozen_update`` (``release`` when
    written)."""

    geometry: GridGeometry
    tile_cells: int
    looks: LooksRule
    layers: dict[Layer, tuple[np.dtype, float | bool, tuple[int, ...]]]
    keys: list[TileKey]
    tiles: Mapping[Layer, Mapping[TileKey, np.ndarray]]
    attrs: dict[str, Any]
    mask: np.ndarray | None
    frozen: FrozenTiles | None = None

    def release(self) -> None:
        """Written (or given up): the grid's tiles are no longer owed to it."""
        if self.frozen is not None:
            self.frozen.release()


def store_update(grid: CoverageGrid, keys: Iterable[TileKey] | None = None) -> StoreUpdate:
    """The tiles ``keys`` (None: every tile the grid holds) of every stored layer of
    ``grid`` and its attributes, copied now (to send to another process): the cost
    follows the tiles, not the grid."""
    todo = grid.tile_keys() if keys is None else sorted(set(keys))
    layers = {layer: grid.layer(layer) for layer in _STORED if grid.keeps(layer)}
    tiles = {layer: {k: t.copy() for k in todo if (t := tiled.get(k)) is not None}
             for layer, tiled in layers.items()}
    return _update(grid, layers, todo, tiles, None)


def frozen_update(grid: CoverageGrid, keys: Iterable[TileKey] | None = None
                  ) -> StoreUpdate:
    """``store_update`` copying nothing now: a tile is copied when the grid next writes
    it or when the update is written, whichever comes first (tiles.FrozenTiles), so that
    taking a checkpoint costs the loop nothing whatever the tiles. One at a time per grid;
    ``release`` it when written."""
    todo = grid.tile_keys() if keys is None else sorted(set(keys))
    layers = {layer: grid.layer(layer) for layer in _STORED if grid.keeps(layer)}
    frozen = FrozenTiles(layers, todo)
    return _update(grid, layers, todo, {layer: frozen.of(layer) for layer in layers},
                   frozen)


def _update(grid: CoverageGrid, layers: Mapping[Layer, TiledLayer], keys: list[TileKey],
            tiles: Mapping[Layer, Mapping[TileKey, np.ndarray]],
            frozen: FrozenTiles | None) -> StoreUpdate:
    latest = grid.latest_frame_t_s
    return _of_layers(grid.free, grid.looks.rule, layers, keys, tiles, frozen, {
        "frames": grid.frames, "frames_blurred": grid.frames_blurred,
        "latest_frame_t_s": latest if math.isfinite(latest) else None})


def layers_update(free: FreeCells, layers: Mapping[Layer, TiledLayer], frames: int
                  ) -> StoreUpdate:
    """Every tile of ``layers`` (a grid of independent looks without a revisit clock, on
    ``free``'s cells: a ground station's copy of a daemon's grid) and ``frames``, copied
    now, as ``store_update`` gives a coverage grid's."""
    keys = sorted({k for t in layers.values() for k in t.tiles})
    tiles = {layer: {k: t.copy() for k, t in tiled.tiles.items()}
             for layer, tiled in layers.items()}
    return _of_layers(free, LooksRule.INDEPENDENT, layers, keys, tiles, None, {
        "frames": frames, "frames_blurred": 0, "latest_frame_t_s": None})


def _of_layers(free: FreeCells, looks: LooksRule, layers: Mapping[Layer, TiledLayer],
               keys: list[TileKey], tiles: Mapping[Layer, Mapping[TileKey, np.ndarray]],
               frozen: FrozenTiles | None, counts: dict[str, Any]) -> StoreUpdate:
    g = free.geometry
    free_space = free.free_space
    attrs = {"pdcov_grid": STORE_VERSION, "x0_m": g.x0_m, "y0_m": g.y0_m,
             "cell_size_m": g.cell_size_m, "n_rows": g.n_rows, "n_cols": g.n_cols,
             "tile_cells": free.layout.size, **counts, "looks": str(looks),
             "free_space_wkb": (None if free_space is None
                                else shapely.to_wkb(free_space, hex=True))}
    return StoreUpdate(
        g, free.layout.size, looks,
        {layer: (t.dtype, t.fill, t.depth) for layer, t in layers.items()}, keys, tiles,
        attrs, free.dense() if free_space is None else None, frozen)


def write_store(path: str | Path, grid: CoverageGrid,
                keys: Iterable[TileKey] | None = None) -> None:
    """``write_update`` of ``store_update(grid, keys)``."""
    write_update(path, store_update(grid, keys))


def write_update(path: str | Path, update: StoreUpdate) -> None:
    """Write ``update`` into the store at ``path``: created for its grid when absent
    (ValueError for a store of another grid), then its tiles, then the attributes.
    OSError from the disk."""
    path = Path(path)
    root = zarr.open_group(store=str(path), mode="a", zarr_format=3)
    if "pdcov_grid" in root.attrs:
        _check_same_grid(path, root.attrs.asdict(), update)
    else:
        _create(root, update)
    arrays = {layer: _array(root, _array_name(update.looks, layer)) for layer in update.layers}
    written = _array(root, _TILES)
    marks = np.asarray(written[...])
    layout = TileLayout(update.geometry.n_rows, update.geometry.n_cols, update.tile_cells)
    for key in update.keys:
        r0, r1, c0, c1 = layout.window_of(key)
        for layer, arr in arrays.items():
            tile = update.tiles[layer].get(key)
            if tile is not None:
                arr[r0:r1, c0:c1] = tile
        marks[key] = 1
    if update.keys:
        written[...] = marks
    root.attrs.update(update.attrs)


def restore_update(update: StoreUpdate, into: CoverageGrid, source: str | Path) -> None:
    """Load ``update`` (a whole grid's: ``store_update`` with no keys) into ``into``, a new
    grid of the same geometry, free cells and looks rule: what another process sent back
    (the many-logs merge). Each tile is checked as a store's are; InputFileError naming
    ``source`` for one that is not."""
    if (update.geometry != into.geometry or update.looks is not into.looks.rule
            or update.tile_cells != into.layout.size):
        raise InputFileError(f"{source}: a grid of another geometry or looks rule")
    path = Path(source)
    for key in update.keys:
        _load_tile(path, into, key, {layer: tiles[key] for layer, tiles in
                                     update.tiles.items() if key in tiles})
    into.frames = _count(path, update.attrs, "frames")
    into.frames_blurred = _count(path, update.attrs, "frames_blurred")
    latest = update.attrs.get("latest_frame_t_s")
    if into.keeps(Layer.LAST_OBS_S) and isinstance(latest, (int, float)):
        into.latest_frame_t_s = float(latest)


def _create(root: zarr.Group, update: StoreUpdate) -> None:
    """The store's arrays for ``update``'s grid: every layer it keeps, the tiles written,
    and the free cells (a mask array when the grid was made from one)."""
    g = update.geometry
    chunks = (update.tile_cells, update.tile_cells)
    for layer, (dtype, fill, depth) in update.layers.items():
        root.create_array(name=_array_name(update.looks, layer), shape=(*g.shape, *depth),
                          chunks=(*chunks, *depth), dtype=dtype, fill_value=fill,
                          compressors=_COMPRESSORS)
    layout = TileLayout(g.n_rows, g.n_cols, update.tile_cells)
    root.create_array(name=_TILES, shape=(layout.n_tile_rows, layout.n_tile_cols),
                      chunks=(layout.n_tile_rows, layout.n_tile_cols), dtype="uint8",
                      fill_value=0)
    if update.mask is not None:
        mask = root.create_array(name="mask", shape=g.shape, chunks=chunks, dtype="bool",
                                 fill_value=False, compressors=_COMPRESSORS)
        mask[...] = update.mask


def _check_same_grid(path: Path, attrs: dict[str, Any], update: StoreUpdate) -> None:
    g = update.geometry
    mine = (g.x0_m, g.y0_m, g.cell_size_m, g.n_rows, g.n_cols, update.tile_cells,
            str(update.looks))
    theirs = tuple(attrs.get(k) for k in ("x0_m", "y0_m", "cell_size_m", "n_rows", "n_cols",
                                          "tile_cells", "looks"))
    if mine != theirs:
        raise ValueError(f"{path}: a store of another grid ({theirs}), not {mine}")


def read_store(path: str | Path, camera: CameraModel, detector: DetectorModel, *,
               max_range_m: float | None = None, min_revisit_s: float | None = None,
               terrain: TerrainSurface | None = None, exposure_s: float | None = None,
               looks: LooksConfig | None = None) -> CoverageGrid:
    """The grid stored at ``path`` (``write_store``), its tiles read and checked as a
    snapshot's arrays are (core/grid_snapshot.py) before any enters the grid; the
    arguments as ``CoverageGrid``'s. InputFileError for a store that is not a readable,
    undamaged pdcov grid (a chunk that does not decode among them), or one of another
    looks rule than ``looks``."""
    path = Path(path)
    try:
        root = zarr.open_group(store=str(path), mode="r", zarr_format=3)
        attrs = root.attrs.asdict()
        geometry, free = _free_cells(path, root, attrs)
        rule = (looks or LooksConfig()).rule
        if attrs.get("looks") != str(rule):
            raise InputFileError(f"{path}: the grid store was made with coverage.looks: "
                                 f"{attrs.get('looks')}, the mission says {rule}; load it "
                                 "with the same looks rule")
        grid = CoverageGrid(geometry, free, camera, detector, max_range_m=max_range_m,
                            min_revisit_s=min_revisit_s, terrain=terrain,
                            exposure_s=exposure_s, looks=looks)
        if attrs.get("tile_cells") != grid.layout.size:
            raise InputFileError(f"{path}: tiles of {attrs.get('tile_cells')} cells, this "
                                 f"pdcov keeps {grid.layout.size}")
        written = np.argwhere(np.asarray(_array(root, _TILES)[...]) != 0)
        arrays = {layer: _array(root, _array_name(rule, layer)) for layer in _STORED
                  if grid.keeps(layer)}
        for tr, tc in written.tolist():
            _read_tile(path, grid, arrays, (tr, tc))
    except _DAMAGED_STORE as e:
        raise InputFileError(f"{path}: not a usable grid store ({type(e).__name__}: "
                             f"{e})") from None
    grid.frames = _count(path, attrs, "frames")
    grid.frames_blurred = _count(path, attrs, "frames_blurred")
    latest = attrs.get("latest_frame_t_s")
    if grid.keeps(Layer.LAST_OBS_S) and isinstance(latest, (int, float)):
        grid.latest_frame_t_s = float(latest)
    return grid


def read_store_like(path: str | Path, like: CoverageGrid) -> CoverageGrid:
    """``read_store`` with ``like``'s camera, detector model and rules (a grid made as the
    stored one was: Mission.new_mission_grid or new_grid)."""
    return read_store(path, like.camera, like.detector, max_range_m=like.max_range_m,
                      min_revisit_s=like.min_revisit_s, terrain=like.terrain,
                      exposure_s=like.exposure_s, looks=like.looks)


def _free_cells(path: Path, root: zarr.Group, attrs: dict[str, Any]
                ) -> tuple[GridGeometry, FreeCells]:
    if attrs.get("pdcov_grid") != STORE_VERSION:
        raise InputFileError(f"{path}: not a pdcov grid store of version {STORE_VERSION} "
                             f"(pdcov_grid: {attrs.get('pdcov_grid')!r})")
    try:
        geometry = GridGeometry(float(attrs["x0_m"]), float(attrs["y0_m"]),
                                float(attrs["cell_size_m"]), int(attrs["n_rows"]),
                                int(attrs["n_cols"]))
        wkb = attrs.get("free_space_wkb")
        if wkb is not None:
            return geometry, FreeCells(geometry, free_space=shapely.from_wkb(wkb))
        mask = _array(root, "mask")
        if mask.shape != geometry.shape:
            raise ValueError(f"mask of shape {mask.shape}")
        return geometry, FreeCells(geometry, mask=np.asarray(mask[...]))
    except shapely.errors.ShapelyError as e:
        raise InputFileError(f"{path}: not a usable grid store (free_space_wkb: {e})") \
            from None


def _read_tile(path: Path, grid: CoverageGrid, arrays: dict[Layer, zarr.Array], key: TileKey
               ) -> None:
    """Tile ``key`` of every stored layer, checked, into ``grid``."""
    r0, r1, c0, c1 = grid.layout.window_of(key)
    if r0 >= r1 or c0 >= c1:
        raise InputFileError(f"{path}: tile {key} lies outside the grid")
    _load_tile(path, grid, key, {layer: np.asarray(arr[r0:r1, c0:c1])
                                 for layer, arr in arrays.items()})


def _load_tile(path: Path, grid: CoverageGrid, key: TileKey,
               values: dict[Layer, np.ndarray]) -> None:
    """Tile ``key``'s arrays (by layer) checked as a snapshot's are, then into ``grid``."""
    window = grid.layout.window_of(key)
    checked = {layer.value: v for layer, v in values.items() if layer is not Layer.LOOKS}
    check_snapshot_values(path, {"mask": grid.read(Layer.MASK, window), **checked})
    looks = grid.looks_model
    state = values.get(Layer.LOOKS)
    if isinstance(looks, ViewpointLooks) and state is not None and state.size \
            and int(state.max()) >= len(looks.log1m_by_rank):
        raise InputFileError(f"{path}: looks_best: ranks above the detector model's "
                             f"{len(looks.log1m_by_rank) - 1}")
    for layer, v in values.items():
        grid.layer(layer).tile(key)[...] = v
    if looks is not None:
        grid.mark_looks_changed(window)


def _count(path: Path, attrs: dict[str, Any], key: str) -> int:
    v = attrs.get(key, 0)
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise InputFileError(f"{path}: {key}: expected a count, got {v!r}")
    return v
