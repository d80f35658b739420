"""Whether the daemon's mission fits the memory it may use: what ``pdcov serve --check``
estimates before the daemon starts, so that a mission that would die of MemoryError in
flight (1e6 frames/s passed the check, then did) is refused on the ground, and one whose
search could outgrow the memory is said to.

The grid holds only the cells frames have seen (tiles, core/tiles.py), so the estimate
(bytes) grows with the area searched, not with the domain: BASE_BYTES for the interpreter,
numpy, OpenCV and Zenoh; one batch of frames evaluated at once (flight/camera_frames.py:
frames spanning a quarter of the tracker's history, max(20 s, 8 x max_gap_s),
BYTES_PER_BATCHED_FRAME each); each camera's grid at BYTES_PER_SEEN_CELL per cell seen (its
layers, and the copies a checkpoint being written may hold); and the snapshot a ground
station is sent: a grid.npz up to bus.grid_state.MAX_CELLS cells,
BYTES_PER_SNAPSHOT_CELL per cell of the domain, tiled above (bus/tiled_snapshot.py),
BYTES_PER_TILED_SNAPSHOT_CELL per cell seen. A mission is refused when not even
SEARCH_MIN_M2 of its free cells searched would fit; it is warned of when its whole domain
searched would not, with the area that fits. The mission's terrain and what stands on it
are held whole (tens of bytes a cell of the grid: ``TerrainSurface.nbytes``) and counted as
loaded. The limit is the least of the cgroup's
memory.max (the systemd unit's MemoryMax) and the machine's MemAvailable, read by
``memory_limit_bytes``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from pdcov.bus.grid_state import MAX_CELLS
from pdcov.flight.camera_frames import BATCH_OF_HISTORY, tracker_history_s

if TYPE_CHECKING:
    from pdcov.config.mission import Mission

__all__ = ["BASE_BYTES", "BYTES_PER_BATCHED_FRAME", "BYTES_PER_SEEN_CELL",
           "BYTES_PER_SNAPSHOT_CELL", "BYTES_PER_TILED_SNAPSHOT_CELL", "MemoryCheck",
           "estimate_bytes", "memory_check", "memory_limit_bytes"]

BASE_BYTES = 150 << 20
BYTES_PER_SEEN_CELL = 32
BYTES_PER_SNAPSHOT_CELL = 64
BYTES_PER_TILED_SNAPSHOT_CELL = 32  # the tiles' 15 wire bytes a cell, joined, and compressed
BYTES_PER_BATCHED_FRAME = 2048
SEARCH_MIN_M2 = 1e6


def estimate_bytes(seen_cells: int, domain_cells: int, frame_rates_hz: Sequence[float],
                   max_gap_s: float) -> int:
    """The estimate (module docstring) with ``seen_cells`` cells seen per camera grid, a
    domain of ``domain_cells`` cells and cameras at ``frame_rates_hz`` (Hz)."""
    batch_s = BATCH_OF_HISTORY * tracker_history_s(max_gap_s)
    batch = sum(rate * batch_s for rate in frame_rates_hz)
    cameras = len(frame_rates_hz) + (len(frame_rates_hz) > 1)  # and the combined grid
    snapshot = (domain_cells * BYTES_PER_SNAPSHOT_CELL if domain_cells <= MAX_CELLS
                else seen_cells * BYTES_PER_TILED_SNAPSHOT_CELL)
    return int(BASE_BYTES + seen_cells * BYTES_PER_SEEN_CELL * cameras + snapshot
               + batch * BYTES_PER_BATCHED_FRAME)


@dataclass(frozen=True, slots=True)
class MemoryCheck:
    """What ``memory_check`` found: ``refusal`` (the mission cannot start) and
    ``warning`` (its whole domain searched would not fit), each None when not so."""

    refusal: str | None
    warning: str | None


def memory_check(mission: Mission, free_cells: int, domain_cells: int,
                 limit: tuple[int, str] | None) -> MemoryCheck:
    """``mission`` (``free_cells`` of ``domain_cells`` per grid) against ``limit`` (bytes,
    and what it is; None: unknown, then nothing is said), naming the figures."""
    if limit is None:
        return MemoryCheck(None, None)
    rates = [c.frame_rate_hz for c in mission.cameras]
    cell_m2 = mission.cell_size_m**2

    terrain = 0 if mission.terrain is None else mission.terrain.nbytes

    def need(seen: int) -> int:
        return estimate_bytes(seen, domain_cells, rates, mission.max_gap_s) + terrain

    least = min(free_cells, int(SEARCH_MIN_M2 / cell_m2))
    if need(least) > limit[0]:
        return MemoryCheck(
            f"the daemon would need about {need(least) / 2**20:,.0f} MiB to search "
            f"{least * cell_m2 / 1e6:.2g} km2 ({least:,} cells of the {domain_cells:,} per "
            f"grid, {', '.join(f'{r:g}' for r in rates)} frames/s), more than the "
            f"{limit[0] / 2**20:,.0f} MiB of {limit[1]}: lower camera.frame_rate_hz, grow "
            "domain.cell_size_m or give the daemon more memory", None)
    if need(free_cells) <= limit[0]:
        return MemoryCheck(None, None)
    spare = limit[0] - need(0)
    cameras = len(rates) + (len(rates) > 1)
    fits = spare // (BYTES_PER_SEEN_CELL * cameras)
    return MemoryCheck(None, (
        f"the {limit[0] / 2**20:,.0f} MiB of {limit[1]} hold about "
        f"{fits * cell_m2 / 1e6:,.1f} km2 searched at {mission.cell_size_m:g} m cells, of "
        f"the domain's {free_cells * cell_m2 / 1e6:,.1f} km2: beyond it the daemon runs "
        "out of memory; give it more (systemd/pdcov.service MemoryMax) or grow "
        "domain.cell_size_m for a longer search"))


def memory_limit_bytes(cgroup_max: Path = Path("/sys/fs/cgroup/memory.max"),
                       meminfo: Path = Path("/proc/meminfo")) -> tuple[int, str] | None:
    """The least of the cgroup's memory.max and MemAvailable (bytes) and which it is; None
    when neither can be read."""
    limits: list[tuple[int, str]] = []
    try:
        text = cgroup_max.read_text().strip()
        if text.isdigit():
            limits.append((int(text), f"{cgroup_max} (the unit's MemoryMax)"))
    except OSError:
        pass
    try:
        for line in meminfo.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                limits.append((int(line.split()[1]) * 1024, f"MemAvailable in {meminfo}"))
    except (OSError, ValueError, IndexError):
        pass
    return min(limits) if limits else None
