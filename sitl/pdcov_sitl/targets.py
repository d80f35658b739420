"""The people the simulated detector looks for (``pdcov-sitl fly --targets N|FILE``).

``place_targets`` scatters N people uniformly over the domain's free space (seeded);
``read_targets`` reads them from a CSV of ``x_m,y_m`` rows (ENU metres about the mission's
origin; a header row naming the columns is optional). Each person stands on the ground:
z_m is the terrain's height there (the mission's terrain), 0 on the flat ground.
``write_targets`` writes ``targets.csv``: id, x_m, y_m, z_m, lat_deg, lon_deg.
Pure but for the two file functions, which open only the paths they are handed.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely

from pdcov.atomic import atomic_write
from pdcov.core.domain import Domain
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.terrain import TerrainSurface
from pdcov.errors import InputFileError

TARGET_CSV_COLUMNS = ("id", "x_m", "y_m", "z_m", "lat_deg", "lon_deg")
MAX_TARGETS = 100_000


@dataclass(frozen=True, slots=True)
class Targets:
    """People on the ground: their ground points (N, 3) in ENU metres; person i has id i."""

    r_enu_m: np.ndarray

    def __post_init__(self) -> None:
        r = np.asarray(self.r_enu_m, dtype=float).reshape(-1, 3)
        if not np.isfinite(r).all():
            raise ValueError("target positions must be finite")
        r.setflags(write=False)
        object.__setattr__(self, "r_enu_m", r)

    def __len__(self) -> int:
        return len(self.r_enu_m)


def on_ground(x_m: np.ndarray, y_m: np.ndarray, terrain: TerrainSurface | None) -> Targets:
    """People standing at (x_m, y_m): on the terrain, or on the flat ground z = 0."""
    x, y = np.asarray(x_m, float), np.asarray(y_m, float)
    z = np.zeros_like(x) if terrain is None else np.asarray(terrain.height_m(x, y), float)
    return Targets(np.stack([x, y, z], axis=-1))


def place_targets(n: int, domain: Domain, terrain: TerrainSurface | None, seed: int
                  ) -> Targets:
    """``n`` people uniformly over the free space (rejection sampling in its bounds)."""
    free = domain.free_space
    shapely.prepare(free)
    x0, y0, x1, y1 = free.bounds
    rng = np.random.default_rng([seed, 0x7A26E7])  # a stream of its own for this seed
    xs: list[np.ndarray] = []
    got = 0
    while got < n:
        batch = rng.uniform((x0, y0), (x1, y1), size=(max(2 * (n - got), 64), 2))
        batch = batch[shapely.contains_xy(free, batch[:, 0], batch[:, 1])]
        xs.append(batch)
        got += len(batch)
    xy = np.concatenate(xs)[:n]
    return on_ground(xy[:, 0], xy[:, 1], terrain)


def read_targets(path: Path, terrain: TerrainSurface | None) -> Targets:
    """People from a CSV of ``x_m,y_m`` rows; a bad row raises InputFileError naming the
    file, the line and what is wrong."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except UnicodeDecodeError:
        raise InputFileError(f"{path}: not a text CSV file of x_m,y_m rows") from None
    xy: list[tuple[float, float]] = []
    for line, row in enumerate(rows, start=1):
        cells = [c.strip() for c in row]
        if not cells or all(not c for c in cells):
            continue
        if line == 1 and [c.lower() for c in cells[:2]] == ["x_m", "y_m"]:
            continue
        try:
            if len(cells) != 2:
                raise ValueError
            x, y = float(cells[0]), float(cells[1])
        except ValueError:
            raise InputFileError(f"{path}: line {line}: expected x_m,y_m (two numbers, ENU "
                                 f"metres), got {','.join(row)[:80]!r}") from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise InputFileError(f"{path}: line {line}: x_m, y_m must be finite, got "
                                 f"{x!r}, {y!r}")
        xy.append((x, y))
    if not 1 <= len(xy) <= MAX_TARGETS:
        raise InputFileError(f"{path}: expected 1..{MAX_TARGETS} x_m,y_m rows, got {len(xy)}")
    a = np.array(xy)
    return on_ground(a[:, 0], a[:, 1], terrain)


def write_targets(path: Path, targets: Targets, origin: Origin) -> None:
    """targets.csv: id, x_m, y_m, z_m (ENU about ``origin``), lat_deg, lon_deg."""
    geo = enu_to_geodetic(targets.r_enu_m, origin).reshape(-1, 3)
    with atomic_write(path, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(TARGET_CSV_COLUMNS)
        for i, (r, g) in enumerate(zip(targets.r_enu_m, geo, strict=True)):
            w.writerow([i, *(f"{v:.4f}" for v in r), f"{g[0]:.9f}", f"{g[1]:.9f}"])
