"""The coverage grid as a subscriber holds it, and the snapshot payload (``.../snapshot``).

A ``GridState`` is what a watcher needs to draw and merge coverage without the camera or
detector: the geometry, the free mask, the log-miss sums ``L`` (float32, ``P = 1 - exp(L)``)
of detection and false alarm, observation counts, the limiting factor per cell and the
daemon's frame count. The daemon's ``CoverageGrid`` holds the same arrays, so a state
rebuilt from a snapshot or from tiles equals the daemon's grid cell for cell (the float32
values travel unchanged).

The snapshot payload is the bytes of the grid.npz that ``CoverageGrid.save_npz`` (and so
``pdcov evaluate``) writes; ``decode_snapshot`` validates it before building anything.
"""

from __future__ import annotations

import hashlib
import io
import math
import re
import struct
import zipfile
from collections.abc import Iterable

import numpy as np

from pdcov.bus.errors import Refusal, Refuser
from pdcov.core.domain import GridGeometry
from pdcov.core.free_cells import FreeCells
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_layer import Layer, Window
from pdcov.core.grid_metrics import limiting_counts
from pdcov.core.grid_snapshot import READABLE_SNAPSHOT_VERSIONS
from pdcov.core.grid_store import StoreUpdate, layers_update
from pdcov.core.limiting import LimitingFactor
from pdcov.core.tiles import TileClock, TiledLayer, TileKey, TileLayout
from pdcov.errors import DomainError
from pdcov.npz_file import DAMAGED

MAX_CELLS = 16_000_000
"""Largest grid a grid.npz snapshot carries (a 4 km square at 1 m): its arrays are whole, so
this bounds what decoding one allocates (checked against the declared shape before anything
is allocated or inflated). A larger grid's snapshot is tiled (bus/tiled_snapshot.py)."""


MAX_SNAPSHOT_BYTES = 128 << 20
"""Largest snapshot payload accepted (a 1 M-cell grid.npz is at most about 37 MB)."""
MAX_ENU_M = 1e7
"""Largest ENU coordinate accepted (beyond it the local flat-earth frame means nothing)."""
GRID_HASH = re.compile(r"[0-9a-f]{16}")
"""A grid hash as written in JSON: 16 lowercase hex digits (``grid_hash``)."""
_NPZ_ARRAYS = ("mask", "log_miss_d", "log_miss_fa", "n_obs", "x0_m", "y0_m", "cell_size_m")


def grid_hash(geometry: GridGeometry, free: np.ndarray | FreeCells) -> str:
    """16 hex digits identifying a grid: SHA-256 of the geometry (little-endian float64 x0_m,
    y0_m, cell_size_m, uint32 n_rows, n_cols) and the free mask (np.packbits, row-major),
    hashed band by band of rows (``FreeCells.packed_rows``): a county's grid is hashed
    without its whole mask. ``free``: a bool mask of the grid's shape, or its FreeCells."""
    if not isinstance(free, FreeCells):
        free = FreeCells(geometry, mask=free)
    elif free.geometry != geometry:
        raise ValueError("grid_hash: the free cells are of another grid geometry")
    h = hashlib.sha256(struct.pack("<dddII", geometry.x0_m, geometry.y0_m,
                                   geometry.cell_size_m, geometry.n_rows, geometry.n_cols))
    for packed in free.packed_rows():
        h.update(packed.tobytes())
    return h.hexdigest()[:16]


class GridState:
    """A coverage grid as a subscriber holds it: its ``geometry``, free cells (``free``,
    ``core.free_cells.FreeCells``), the log-miss sums of detection and false alarm (float32,
    <= 0, ``P = 1 - exp(L)``), observation counts (int32; int64 in a fleet's merge), the
    limiting factor per cell (uint8 LimitingFactor codes; ``limiting_known`` False: unknown,
    from a pdcov before tiles version 2) and the daemon's frame count. The layers are kept in
    tiles allocated when first written (``core.tiles``), as the daemon's grid keeps them:
    memory follows the cells seen, not the domain. Read by window (``read``, the
    ``CellSource`` protocol) or, up to ``tiles.MAX_DENSE_CELLS`` cells, whole through the
    read-only properties ``mask``, ``log_miss_d``, ``log_miss_fa``, ``n_obs``, ``limiting``
    and ``pd``; written by window (``write``)."""

    def __init__(self, geometry: GridGeometry, free: np.ndarray | FreeCells, *,
                 frames: int = 0, limiting_known: bool = True,
                 n_obs_dtype: type = np.int32) -> None:
        if not isinstance(free, FreeCells):
            free = FreeCells(geometry, mask=free)
        elif free.geometry != geometry:
            raise ValueError("GridState: the free cells are of another grid geometry")
        self.geometry = geometry
        self.free = free
        self.frames = frames
        self.limiting_known = limiting_known
        layout, clock = free.layout, TileClock()
        self._layers: dict[Layer, TiledLayer] = {
            Layer.LOG_MISS_D: TiledLayer(layout, np.float32, 0.0, clock=clock),
            Layer.LOG_MISS_FA: TiledLayer(layout, np.float32, 0.0, clock=clock),
            Layer.N_OBS: TiledLayer(layout, n_obs_dtype, 0, clock=clock),
            Layer.LIMITING: TiledLayer(layout, np.uint8, LimitingFactor.NEVER_IN_VIEW,
                                       clock=clock)}

    @classmethod
    def empty(cls, geometry: GridGeometry, free: np.ndarray | FreeCells) -> GridState:
        """No look yet: every layer its fill."""
        return cls(geometry, free)

    @classmethod
    def from_arrays(cls, geometry: GridGeometry, mask: np.ndarray, log_miss_d: np.ndarray,
                    log_miss_fa: np.ndarray, n_obs: np.ndarray, frames: int = 0,
                    limiting: np.ndarray | None = None) -> GridState:
        """A state holding these whole arrays (copied; tiles of fill values not allocated;
        ``limiting`` None: unknown)."""
        state = cls(geometry, np.array(mask, dtype=bool), frames=frames,
                    limiting_known=limiting is not None)
        whole = (0, geometry.n_rows, 0, geometry.n_cols)
        for layer, values in ((Layer.LOG_MISS_D, log_miss_d), (Layer.LOG_MISS_FA, log_miss_fa),
                              (Layer.N_OBS, n_obs), (Layer.LIMITING, limiting)):
            if values is not None:
                state.write(layer, whole, values)
        return state

    @classmethod
    def from_grid(cls, grid: CoverageGrid) -> GridState:
        """A copy of a CoverageGrid's stored layers (its free cells shared: they never
        change)."""
        state = cls(grid.geometry, grid.free, frames=grid.frames)
        for layer, mine in state._layers.items():
            for key, tile in grid.layer(layer).tiles.items():
                mine.tile(key)[...] = tile
        return state

    def copy(self) -> GridState:
        """A copy of the layers (the geometry and free cells are immutable)."""
        out = GridState(self.geometry, self.free, frames=self.frames,
                        limiting_known=self.limiting_known,
                        n_obs_dtype=self._layers[Layer.N_OBS].dtype.type)
        for layer, mine in self._layers.items():
            for key, tile in mine.tiles.items():
                out._layers[layer].tile(key)[...] = tile
        return out

    @property
    def hash(self) -> str:
        return grid_hash(self.geometry, self.free)

    @property
    def layout(self) -> TileLayout:
        """How the layers are cut into tiles (the free cells')."""
        return self.free.layout

    @property
    def n_free(self) -> int:
        return self.free.n_free

    @property
    def nbytes(self) -> int:
        """Bytes held by the tiles written."""
        return sum(lay.nbytes for lay in self._layers.values())

    def tiles(self, layer: Layer) -> dict[TileKey, np.ndarray]:
        """The tiles of a stored layer written so far, by key (read them, do not write)."""
        return self._layers[layer].tiles

    def tile_keys(self) -> list[TileKey]:
        """The tiles written in any layer, row by row."""
        keys: set[TileKey] = set()
        for lay in self._layers.values():
            keys.update(lay.tiles)
        return sorted(keys)

    def written_windows(self) -> list[Window]:
        """Each written tile's cells, row by row (``CellSource``)."""
        return [self.layout.window_of(k) for k in self.tile_keys()]

    def read(self, layer: Layer, window: Window | None = None) -> np.ndarray:
        """The cells of ``window`` (None: all) of ``layer`` (``core.grid_layer.CellSource``):
        a new array. ValueError for the limiting factors when unknown, or a layer a
        subscriber does not hold."""
        w = window or (0, self.geometry.n_rows, 0, self.geometry.n_cols)
        if layer is Layer.PD or layer is Layer.PFA:
            source = Layer.LOG_MISS_D if layer is Layer.PD else Layer.LOG_MISS_FA
            return 0.0 - np.expm1(self._layers[source].read(w).astype(np.float64))
        if layer is Layer.MASK:
            return np.array(self.free.window(w))
        if layer is Layer.LIMITING and not self.limiting_known:
            raise ValueError("a ground station's grid holds no limiting (limiting factors "
                             "unknown)")
        found = self._layers.get(layer)
        if found is None:
            raise ValueError(f"a ground station's grid holds no {layer.value}")
        return found.read(w)

    def write(self, layer: Layer, window: Window, values: np.ndarray | float) -> None:
        """Set the cells of ``window`` of a stored layer to ``values``."""
        self._layers[layer].write(window, values)

    def limiting_counts(self) -> dict[str, int]:
        """Free cells per LimitingFactor, by lower-case name (``grid_metrics``'s rule, tile
        by tile). ValueError when unknown."""
        if not self.limiting_known:
            raise ValueError("the grid's limiting factors are unknown")
        return limiting_counts(self._layers[Layer.LIMITING].tiles, self.free)

    def store_update(self) -> StoreUpdate:
        """Every tile written, as a grid store takes them (core/grid_store.py; the limiting
        factors only when known)."""
        return layers_update(self.free, {
            layer: tiled for layer, tiled in self._layers.items()
            if layer is not Layer.LIMITING or self.limiting_known}, self.frames)

    def forget_limiting(self) -> None:
        """The limiting factors became unknown (cells rewritten by a version-1 tiles
        message may have changed theirs)."""
        self.limiting_known = False

    # The whole grid's layers as read-only arrays, up to tiles.MAX_DENSE_CELLS cells.

    @property
    def mask(self) -> np.ndarray:
        return self.free.dense()

    @property
    def log_miss_d(self) -> np.ndarray:
        return self._layers[Layer.LOG_MISS_D].dense()

    @property
    def log_miss_fa(self) -> np.ndarray:
        return self._layers[Layer.LOG_MISS_FA].dense()

    @property
    def n_obs(self) -> np.ndarray:
        return self._layers[Layer.N_OBS].dense()

    @property
    def limiting(self) -> np.ndarray | None:
        """The limiting factors, None when unknown."""
        return self._layers[Layer.LIMITING].dense() if self.limiting_known else None

    @property
    def pd(self) -> np.ndarray:
        """Cumulative P_D per cell (float64), computed as CoverageGrid.pd does."""
        return 0.0 - np.expm1(self.log_miss_d.astype(np.float64))

    def proportion_at_or_above(self, threshold: float) -> float:
        """Share of free cells whose P_D is at least ``threshold``."""
        return self.proportions_at_or_above((threshold,))[float(threshold)]

    def proportions_at_or_above(self, thresholds: Iterable[float]) -> dict[float, float]:
        """{threshold: share of free cells whose P_D is at least it}, read tile by tile: a
        tile never written has P_D 0, which only thresholds <= 0 count."""
        wanted = [float(t) for t in thresholds]
        n = self.n_free
        counts = dict.fromkeys(wanted, 0)
        for window in self.written_windows():
            pd = self.read(Layer.PD, window)[self.free.window(window)]
            for t in wanted:
                if t > 0:
                    counts[t] += int(np.count_nonzero(pd >= t))
        return {t: (counts[t] if t > 0 else n) / n if n else 0.0 for t in wanted}


def encode_snapshot(grid: CoverageGrid) -> bytes:
    """The grid.npz bytes of ``grid`` (CoverageGrid.write_npz; np.load reads them)."""
    buf = io.BytesIO()
    grid.write_npz(buf)
    return buf.getvalue()


def decode_snapshot(payload: bytes, key: str = "snapshot",
                    max_cells: int = MAX_CELLS) -> GridState:
    """Validate grid.npz bytes and return their GridState. Checks: at most
    MAX_SNAPSHOT_BYTES, a zip of .npy arrays (no pickles) whose headers declare a grid of
    at most ``max_cells`` cells (read before any array is inflated; ``pd`` and ``pfa`` are
    not read), the snapshot version, every array present with the mask's shape and a
    numeric dtype, finite log-miss sums <= 0, observation counts >= 0, limiting codes in
    0..5 (when present: snapshots before version 3 lack them, the state's limiting is then
    None), a frame count in 0..2**32 - 1, a valid geometry. Raises BusPayloadError naming
    ``key`` (its ``reason`` says why)."""
    bad = Refuser(f"{key}: not a usable grid snapshot")
    data = bytes(payload)
    if len(data) > MAX_SNAPSHOT_BYTES:
        raise bad(f"{len(data)} bytes, more than {MAX_SNAPSHOT_BYTES}", Refusal.TOO_LARGE)
    arrays = _read_arrays(data, max_cells, bad)
    version = _scalar(arrays, "version", "iu", bad)
    if version not in READABLE_SNAPSHOT_VERSIONS:
        raise bad(f"snapshot version {version:g}, expected "
                  f"{', '.join(map(str, READABLE_SNAPSHOT_VERSIONS))}", Refusal.MALFORMED)
    mask = arrays["mask"]
    if mask.dtype != np.bool_:
        raise bad(f"mask: expected a 2-D bool array, got {mask.dtype} {mask.shape}")
    for name, kind in (("log_miss_d", "f"), ("log_miss_fa", "f"), ("n_obs", "iu"),
                       ("limiting", "iu")):
        a = arrays.get(name)
        if a is None:  # limiting, optional (_read_arrays checks the others are there)
            continue
        if a.shape != mask.shape or a.dtype.kind not in kind:
            raise bad(f"{name}: expected {mask.shape} numbers, got {a.dtype} {a.shape}")
    scalars = {name: _scalar(arrays, name, "fiu", bad)
               for name in ("x0_m", "y0_m", "cell_size_m")}
    if not all(abs(scalars[n]) <= MAX_ENU_M for n in ("x0_m", "y0_m")):
        raise bad(f"x0_m, y0_m: expected metres within {MAX_ENU_M:g}")
    frames = _scalar(arrays, "frames", "iu", bad, default=0)
    if not 0 <= frames <= 2**32 - 1:
        raise bad(f"frames: {frames:g}, expected a count in 0..2**32-1")
    try:
        geometry = GridGeometry(scalars["x0_m"], scalars["y0_m"], scalars["cell_size_m"],
                                *mask.shape)
    except DomainError as exc:
        raise bad(str(exc)) from None
    limiting = arrays.get("limiting")
    check_values(arrays["log_miss_d"], arrays["log_miss_fa"], arrays["n_obs"], bad, limiting)
    return GridState.from_arrays(geometry, mask, arrays["log_miss_d"].astype(np.float32),
                                 arrays["log_miss_fa"].astype(np.float32),
                                 arrays["n_obs"].astype(np.int32), int(frames),
                                 None if limiting is None else limiting.astype(np.uint8))


def _read_arrays(data: bytes, max_cells: int, bad: Refuser) -> dict[str, np.ndarray]:
    """The arrays of _NPZ_ARRAYS (and ``version``, ``frames``, ``limiting`` when present) of
    an .npz;
    every .npy header is read and bounded (the mask 2-D and at most ``max_cells``, the
    others at most as many values, none of objects or wider than 8 bytes) before any array
    is inflated, so a small payload cannot declare a huge grid."""
    wanted = set(_NPZ_ARRAYS) | {"version", "frames", "limiting"}
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            members = {i.filename.removesuffix(".npy"): i for i in zf.infolist()
                       if i.filename.removesuffix(".npy") in wanted}
            missing = sorted(set(_NPZ_ARRAYS) - set(members))
            if missing:
                raise bad(f"missing {', '.join(missing)}", Refusal.MALFORMED)
            for name, info in members.items():
                with zf.open(info) as fh:
                    major, _ = np.lib.format.read_magic(fh)
                    read_header = (np.lib.format.read_array_header_1_0 if major == 1
                                   else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = read_header(fh)
                n = math.prod(shape)
                if name == "mask" and (len(shape) != 2 or n > max_cells):
                    raise bad(f"mask: shape {shape}, expected a 2-D grid of at most "
                              f"MAX_CELLS {max_cells} cells", Refusal.OVER_BOUND
                              if len(shape) == 2 else Refusal.BAD_FIELD)
                if n > max_cells or dtype.hasobject or dtype.itemsize > 8:
                    raise bad(f"{name}: {dtype} {shape}, expected at most {max_cells} "
                              "numbers", Refusal.OVER_BOUND)
            out = {}
            for name, info in members.items():
                with zf.open(info) as fh:
                    out[name] = np.lib.format.read_array(fh, allow_pickle=False)
            return out
    except DAMAGED as exc:
        raise bad(f"not an .npz of .npy arrays ({type(exc).__name__}: {exc})"[:300],
                  Refusal.MALFORMED) from None


def _scalar(arrays: dict[str, np.ndarray], name: str, kinds: str, bad: Refuser,
            default: float | None = None) -> float:
    """The finite number in the one-value array ``name`` (of a dtype kind in ``kinds``)."""
    a = arrays.get(name)
    if a is None and default is not None:
        return default
    if a is None or a.size != 1 or a.dtype.kind not in kinds \
            or not math.isfinite(float(a.reshape(()))):
        raise bad(f"{name}: expected one finite number")
    return float(a.reshape(()))


def check_values(log_miss_d: np.ndarray, log_miss_fa: np.ndarray, n_obs: np.ndarray,
                 bad: Refuser, limiting: np.ndarray | None = None) -> None:
    """Raise ``bad(why)`` unless the log-miss sums are <= 0 (-inf allowed: a cell with
    P = 1) and not NaN, the counts lie in 0..2**31 - 1 and the limiting codes (when given)
    are LimitingFactor values."""
    for name, a in (("log_miss_d", log_miss_d), ("log_miss_fa", log_miss_fa)):
        if np.isnan(a).any() or (a > 0).any():
            raise bad(f"{name}: values must be <= 0 and not NaN")
    if n_obs.size and (int(n_obs.min()) < 0 or int(n_obs.max()) > 2**31 - 1):
        raise bad("n_obs: counts must lie in 0..2**31-1")
    top = int(max(LimitingFactor))
    if limiting is not None and limiting.size and (int(limiting.min()) < 0
                                                   or int(limiting.max()) > top):
        raise bad(f"limiting: codes must lie in 0..{top} (LimitingFactor)")
