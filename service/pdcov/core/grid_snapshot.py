"""The coverage grid's snapshot file (.npz): what ``CoverageGrid.save_npz`` writes and
``CoverageGrid.load_npz`` reads back, checked before any of it enters a grid.

Arrays (the grid's shape unless said): pd, pfa (float64), n_obs (int32), mask (bool), the
log-miss sums log_miss_d and log_miss_fa (float32, <= 0), limiting (LimitingFactor codes,
uint8; optional), with ``min_revisit_s`` last_obs_s (s, float64; float32 in version 1), the
looks state (looks_counts or looks_best, ``core/looks.py``), and the scalars x0_m, y0_m
(m, ENU: south-west corner of cell [0, 0]), cell_size_m, frames, version and looks (the
rule's name).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING

import numpy as np

from pdcov.atomic import atomic_write
from pdcov.core.domain import GridGeometry
from pdcov.core.grid_layer import Layer
from pdcov.core.limiting import LimitingFactor
from pdcov.core.looks import CorrelatedLooks, LooksRule, ViewpointLooks
from pdcov.errors import InputFileError
from pdcov.npz_file import read_npz

if TYPE_CHECKING:
    from pdcov.core.grid import CoverageGrid

_LOOKS_KEY = {CorrelatedLooks: "looks_counts", ViewpointLooks: "looks_best"}

SNAPSHOT_VERSION = 3  # 3: the looks state; 2: the revisit clock in float64; 1: float32
READABLE_SNAPSHOT_VERSIONS = (1, 2, 3)
# A version-1 revisit clock (float32) is used only where it resolves 1 ms: times below 2^13 s.
_FLOAT32_CLOCK_LIMIT_S = 2.0**13


def save_snapshot(grid: CoverageGrid, path: str | Path, *, with_limiting: bool = True) -> None:
    """Write ``grid``'s snapshot to ``path`` atomically (temp file, fsync, rename); without
    limiting when ``with_limiting`` is False (a grid whose limiting factors are unknown)."""
    with atomic_write(path, "wb") as fh:
        write_snapshot(grid, fh, with_limiting=with_limiting)


def write_snapshot(grid: CoverageGrid, fh: IO[bytes], *, with_limiting: bool = True) -> None:
    """Write ``grid``'s snapshot to an open binary file (the daemon sends these bytes over
    Zenoh: np.load reads them)."""
    g = grid.geometry
    optional: dict[str, np.ndarray] = (
        {} if grid.last_obs_s is None else {"last_obs_s": grid.last_obs_s})
    if with_limiting:
        optional["limiting"] = grid.limiting
    looks = grid.looks_model
    if looks is not None:
        optional[_LOOKS_KEY[type(looks)]] = grid.read(Layer.LOOKS)
    np.savez_compressed(
        fh, version=SNAPSHOT_VERSION, pd=grid.pd, pfa=grid.pfa, n_obs=grid.n_obs,
        mask=grid.mask, log_miss_d=grid.log_miss_d, log_miss_fa=grid.log_miss_fa,
        x0_m=g.x0_m, y0_m=g.y0_m, cell_size_m=g.cell_size_m,
        frames=grid.frames, looks=str(grid.looks.rule),
        **optional)  # type: ignore[arg-type]  # mypy matches **optional to allow_pickle


@dataclass(frozen=True, slots=True, eq=False)
class Snapshot:
    """A snapshot read and checked (``read_snapshot``): its ``path`` (for messages), format
    ``version``, the grid's ``geometry`` and free-space ``mask``, and its ``arrays``."""

    path: Path
    version: int
    geometry: GridGeometry
    mask: np.ndarray
    arrays: dict[str, np.ndarray]

    def restore(self, grid: CoverageGrid) -> None:
        """Load the sums, counts, limiting factors, frame count, looks state and revisit
        clock into ``grid``, a new grid of this snapshot's geometry and mask. A version-1
        revisit clock (float32) is refused where it cannot resolve a millisecond (times of
        2^13 s and more, e.g. Unix epoch times) when ``grid`` uses one; a snapshot of
        another looks rule than the grid's is refused (InputFileError)."""
        path, data, mask = self.path, self.arrays, self.mask
        everything = (0, grid.geometry.n_rows, 0, grid.geometry.n_cols)

        def write(layer: Layer, values: np.ndarray) -> None:
            grid.layer(layer).write(everything, values)

        write(Layer.LOG_MISS_D, data["log_miss_d"])  # a new grid: nothing to refresh
        _load_looks(path, data, grid)
        write(Layer.LOG_MISS_FA, data["log_miss_fa"])
        write(Layer.N_OBS, data["n_obs"])
        if "limiting" in data:
            write(Layer.LIMITING, data["limiting"])
        else:  # written before limiting factors: what the sums and counts still tell
            write(Layer.LIMITING, np.where(
                data["log_miss_d"] < 0, LimitingFactor.SEEN,
                np.where(data["n_obs"] > 0, LimitingFactor.TOO_SMALL,
                         LimitingFactor.NEVER_IN_VIEW)))
        grid.frames = int(data.get("frames", 0))
        if grid.keeps(Layer.LAST_OBS_S) and "last_obs_s" in data:
            last = data["last_obs_s"]
            if last.shape != mask.shape:
                raise InputFileError(f"{path}: last_obs_s has shape {last.shape}, the mask "
                                     f"{mask.shape}")
            finite = last[np.isfinite(last)]
            latest = float(finite.max()) if finite.size else -math.inf
            if (self.version == 1 and finite.size
                    and np.abs(finite).max() >= _FLOAT32_CLOCK_LIMIT_S):
                raise InputFileError(
                    f"{path}: grid snapshot version 1 keeps the revisit clock in float32, "
                    f"which resolves only {np.spacing(np.float32(latest)):g} s at t = "
                    f"{latest:.0f} s; re-create the grid with this pdcov, or load it "
                    "without coverage.min_revisit_s")
            write(Layer.LAST_OBS_S, last)
            grid.latest_frame_t_s = float(data.get("latest_frame_t_s", latest))


def read_snapshot(path: str | Path, data: bytes | None = None) -> Snapshot:
    """Read a snapshot written by ``save_snapshot`` (version 3, 2 or 1) from ``path``, or
    from its bytes ``data`` (``path`` then names it in messages), refusing (InputFileError)
    one that is not a readable, undamaged grid snapshot."""
    path = Path(path)
    arrays = read_npz(path if data is None else data, lambda why: InputFileError(
        f"{path}: cannot read grid snapshot ({why})"))
    missing = {"mask", "log_miss_d", "log_miss_fa", "n_obs", "x0_m", "y0_m",
               "cell_size_m"} - set(arrays)
    if missing:
        raise InputFileError(f"{path}: not a pdcov grid snapshot (missing "
                             f"{', '.join(sorted(missing))})")
    version = int(arrays.get("version", 1))
    if version not in READABLE_SNAPSHOT_VERSIONS:
        raise InputFileError(f"{path}: grid snapshot version {version}, expected "
                             f"{' or '.join(map(str, READABLE_SNAPSHOT_VERSIONS))}")
    check_snapshot_values(path, arrays)
    mask = arrays["mask"].astype(bool)
    geometry = GridGeometry(float(arrays["x0_m"]), float(arrays["y0_m"]),
                            float(arrays["cell_size_m"]), *mask.shape)
    return Snapshot(path, version, geometry, mask, arrays)


def check_snapshot_values(path: Path, data: dict[str, np.ndarray]) -> None:
    """Refuse (InputFileError) a snapshot whose arrays could not have been written by
    ``write_snapshot``: shapes other than the mask's, non-numeric arrays, NaN or positive log-miss
    sums, counts outside 0..2^31-1, a non-finite geometry, a negative frame count, a NaN
    revisit clock. So a damaged file is never half loaded into a grid."""
    def bad(why: str) -> InputFileError:
        return InputFileError(f"{path}: not a usable grid snapshot: {why}")

    mask = data["mask"]
    if mask.ndim != 2 or mask.dtype.kind not in "bui":
        raise bad(f"mask: expected a 2-D boolean array, got {mask.dtype} {mask.shape}")
    for key, kinds in (("log_miss_d", "f"), ("log_miss_fa", "f"), ("n_obs", "iu"),
                       ("last_obs_s", "f"), ("limiting", "iu")):
        a = data.get(key)
        if a is None:
            continue
        if a.shape != mask.shape:
            raise InputFileError(f"{path}: {key} has shape {a.shape}, the mask {mask.shape}")
        if a.dtype.kind not in kinds:
            raise bad(f"{key}: expected numbers, got {a.dtype}")
        if np.isnan(a).any():
            raise bad(f"{key}: NaN values")
    for key in ("log_miss_d", "log_miss_fa"):
        if (data[key] > 0).any():
            raise bad(f"{key}: positive values (log-miss sums are <= 0)")
    limiting = data.get("limiting")
    if limiting is not None and limiting.size and (
            int(limiting.min()) < 0 or int(limiting.max()) > max(LimitingFactor)):
        raise bad(f"limiting: codes outside 0..{int(max(LimitingFactor))}")
    n_obs = data["n_obs"]
    if n_obs.size and (int(n_obs.min()) < 0 or int(n_obs.max()) > 2**31 - 1):
        raise bad("n_obs: counts outside 0..2^31-1")
    for key in ("x0_m", "y0_m", "cell_size_m", "frames", "version"):
        a = data.get(key)
        if a is not None and (a.size != 1 or a.dtype.kind not in "fiu"
                              or not math.isfinite(float(a))):
            raise bad(f"{key}: expected one finite number")
    if int(data.get("frames", 0)) < 0:
        raise bad("frames: negative")


def _load_looks(path: Path, data: dict[str, np.ndarray], grid: CoverageGrid) -> None:
    """Restore a snapshot's looks state into ``grid``, refusing a snapshot of another rule
    (InputFileError)."""
    written = str(data["looks"]) if "looks" in data else str(LooksRule.INDEPENDENT)
    rule = grid.looks.rule
    if written != str(rule):
        raise InputFileError(f"{path}: the grid snapshot was made with coverage.looks: "
                             f"{written}, the mission says {rule}; load it with the same "
                             "looks rule")
    looks = grid.looks_model
    if looks is None:
        return
    key = _LOOKS_KEY[type(looks)]
    shape = (*grid.geometry.shape, *looks.depth)
    a = data.get(key)
    if a is None or a.shape != shape or a.dtype != looks.dtype:
        raise InputFileError(
            f"{path}: {key}: expected {looks.dtype} {shape} (the {rule} looks of "
            f"this mission's grid and detector model), got "
            f"{'nothing' if a is None else f'{a.dtype} {a.shape}'}")
    if isinstance(looks, ViewpointLooks) and a.size and int(a.max()) >= len(
            looks.log1m_by_rank):
        raise InputFileError(f"{path}: looks_best: ranks above the detector model's "
                             f"{len(looks.log1m_by_rank) - 1}")
    everything = (0, grid.geometry.n_rows, 0, grid.geometry.n_cols)
    grid.layer(Layer.LOOKS).write(everything, a)
    grid.mark_looks_changed(everything)
