"""The coverage grid as a subscriber holds it, and the snapshot payload (``.../snapshot``).

A ``GridState`` is what a watcher needs to draw and merge coverage without the camera or
detector: the geometry, the free mask, the log-miss sums ``L`` (float32, ``P = 1 - exp(L)``)
of detection and false alarm, observation counts and the daemon's frame count. The daemon's
``CoverageGrid`` holds the same arrays, so a state rebuilt from a snapshot or from tiles
equals the daemon's grid cell for cell (the float32 values travel unchanged).

The snapshot payload is the bytes of the grid.npz that ``CoverageGrid.save_npz`` (and so
``pdcov evaluate``) writes; ``decode_snapshot`` validates it before building anything.
"""

from __future__ import annotations

import hashlib
import io
import math
import struct
import zipfile
from dataclasses import dataclass

import numpy as np

from pdcov.bus.errors import BusPayloadError
from pdcov.core.domain import GridGeometry
from pdcov.core.grid import SNAPSHOT_VERSION, CoverageGrid
from pdcov.errors import DomainError
from pdcov.npz_file import DAMAGED, read_npz

MAX_CELLS = 50_000_000
"""Largest grid a decoder accepts (a 7 km square at 1 m): a bound on memory, not a limit of
the format."""
_NPZ_ARRAYS = ("mask", "log_miss_d", "log_miss_fa", "n_obs", "x0_m", "y0_m", "cell_size_m")


def grid_hash(geometry: GridGeometry, mask: np.ndarray) -> str:
    """16 hex digits identifying a grid: SHA-256 of the geometry (little-endian float64 x0_m,
    y0_m, cell_size_m, uint32 n_rows, n_cols) and the free mask (np.packbits, row-major)."""
    head = struct.pack("<dddII", geometry.x0_m, geometry.y0_m, geometry.cell_size_m,
                       geometry.n_rows, geometry.n_cols)
    packed = np.packbits(np.asarray(mask, dtype=bool).ravel()).tobytes()
    return hashlib.sha256(head + packed).hexdigest()[:16]


@dataclass(slots=True)
class GridState:
    """A coverage grid's arrays: mask bool, log_miss_d / log_miss_fa float32 (<= 0), n_obs
    int32, all (n_rows, n_cols); frames counted by the daemon."""

    geometry: GridGeometry
    mask: np.ndarray
    log_miss_d: np.ndarray
    log_miss_fa: np.ndarray
    n_obs: np.ndarray
    frames: int = 0

    @classmethod
    def empty(cls, geometry: GridGeometry, mask: np.ndarray) -> GridState:
        shape = geometry.shape
        return cls(geometry, np.asarray(mask, bool).copy(), np.zeros(shape, np.float32),
                   np.zeros(shape, np.float32), np.zeros(shape, np.int32))

    @classmethod
    def from_grid(cls, grid: CoverageGrid) -> GridState:
        """A copy of a CoverageGrid's arrays."""
        return cls(grid.geometry, grid.mask.copy(), grid.log_miss_d.copy(),
                   grid.log_miss_fa.copy(), grid.n_obs.copy(), grid.frames)

    @property
    def hash(self) -> str:
        return grid_hash(self.geometry, self.mask)

    @property
    def pd(self) -> np.ndarray:
        """Cumulative P_D per cell (float64), computed as CoverageGrid.pd does."""
        return 0.0 - np.expm1(self.log_miss_d.astype(np.float64))

    def proportion_at_or_above(self, threshold: float) -> float:
        """Share of free cells whose P_D is at least ``threshold``."""
        n = int(self.mask.sum())
        return float((self.pd[self.mask] >= threshold).sum() / n) if n else 0.0


def encode_snapshot(grid: CoverageGrid) -> bytes:
    """The grid.npz bytes of ``grid`` (CoverageGrid.write_npz; np.load reads them)."""
    buf = io.BytesIO()
    grid.write_npz(buf)
    return buf.getvalue()


def decode_snapshot(payload: bytes, key: str = "snapshot",
                    max_cells: int = MAX_CELLS) -> GridState:
    """Validate grid.npz bytes and return their GridState. Checks: a zip of .npy arrays
    (no pickles) whose uncompressed size fits ``max_cells``, the snapshot version, every
    array present with the mask's shape and a numeric dtype, finite log-miss sums <= 0,
    observation counts >= 0, a valid geometry. Raises BusPayloadError naming ``key``."""
    def bad(why: str) -> BusPayloadError:
        return BusPayloadError(f"{key}: not a usable grid snapshot: {why}")

    try:
        with zipfile.ZipFile(io.BytesIO(bytes(payload))) as zf:
            total = sum(i.file_size for i in zf.infolist())
    except DAMAGED as exc:
        raise bad(f"not an .npz (zip) file ({exc})") from None
    if total > 4 * 16 * max_cells + (1 << 20):  # four 4-byte arrays, float64 pd/pfa, slack
        raise bad(f"{total} bytes uncompressed, more than a grid of {max_cells} cells")
    data = read_npz(bytes(payload), bad)
    missing = sorted(set(_NPZ_ARRAYS) - set(data))
    if missing:
        raise bad(f"missing {', '.join(missing)}")
    version = int(data["version"]) if "version" in data and data["version"].size == 1 else -1
    if version not in (1, SNAPSHOT_VERSION):
        raise bad(f"snapshot version {version}, expected 1 or {SNAPSHOT_VERSION}")
    mask = data["mask"]
    if mask.ndim != 2 or mask.dtype != np.bool_:
        raise bad(f"mask: expected a 2-D bool array, got {mask.dtype} {mask.shape}")
    for name, kind in (("log_miss_d", "f"), ("log_miss_fa", "f"), ("n_obs", "iu")):
        a = data[name]
        if a.shape != mask.shape or a.dtype.kind not in kind:
            raise bad(f"{name}: expected {mask.shape} numbers, got {a.dtype} {a.shape}")
    scalars = {}
    for name in ("x0_m", "y0_m", "cell_size_m"):
        a = data[name]
        if a.size != 1 or a.dtype.kind not in "fiu" or not math.isfinite(float(a)):
            raise bad(f"{name}: expected a finite number")
        scalars[name] = float(a)
    try:
        geometry = GridGeometry(scalars["x0_m"], scalars["y0_m"], scalars["cell_size_m"],
                                *mask.shape)
    except DomainError as exc:
        raise bad(str(exc)) from None
    state = GridState(geometry, mask.copy(), data["log_miss_d"].astype(np.float32),
                      data["log_miss_fa"].astype(np.float32), data["n_obs"].astype(np.int64),
                      int(data["frames"]) if "frames" in data and data["frames"].size == 1
                      else 0)
    check_values(state.log_miss_d, state.log_miss_fa, state.n_obs, bad)
    state.n_obs = state.n_obs.astype(np.int32)
    return state


def check_values(log_miss_d: np.ndarray, log_miss_fa: np.ndarray, n_obs: np.ndarray,
                 bad) -> None:
    """Raise ``bad(why)`` unless the log-miss sums are <= 0 (-inf allowed: a cell with
    P = 1) and not NaN, and the counts lie in 0..2**31 - 1."""
    for name, a in (("log_miss_d", log_miss_d), ("log_miss_fa", log_miss_fa)):
        if np.isnan(a).any() or (a > 0).any():
            raise bad(f"{name}: values must be <= 0 and not NaN")
    if n_obs.size and (int(n_obs.min()) < 0 or int(n_obs.max()) > 2**31 - 1):
        raise bad("n_obs: counts must lie in 0..2**31-1")
