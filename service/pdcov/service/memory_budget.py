"""Whether the daemon's mission fits the memory it may use: what ``pdcov serve --check``
estimates before the daemon starts, so that a mission that would die of MemoryError in
flight (1e6 frames/s passed the check, then did) is refused on the ground.

The estimate (bytes) is the largest two things the daemon holds: each camera's grid (its
arrays, the snapshot being encoded, the tile diff: BYTES_PER_CELL per cell) and one batch of
frames evaluated at once (flight/camera_frames.py: frames spanning a quarter of the
tracker's history, max(20 s, 8 x max_gap_s), BYTES_PER_BATCHED_FRAME each: the tracker's
interpolated poses, rotations, motion and masks), on top of BASE_BYTES for the interpreter,
numpy, OpenCV and Zenoh. The limit is the least of the cgroup's memory.max (the systemd
unit's MemoryMax) and the machine's MemAvailable, read by ``memory_limit_bytes``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from pdcov.flight.camera_frames import BATCH_OF_HISTORY, tracker_history_s

if TYPE_CHECKING:
    from pdcov.config.mission import Mission

__all__ = ["BASE_BYTES", "BYTES_PER_BATCHED_FRAME", "BYTES_PER_CELL", "estimate_bytes",
           "memory_limit_bytes", "memory_refusal"]

BASE_BYTES = 150 << 20
BYTES_PER_CELL = 64
BYTES_PER_BATCHED_FRAME = 2048


def estimate_bytes(n_cells: int, frame_rates_hz: Sequence[float], max_gap_s: float) -> int:
    """The estimate (module docstring) for ``n_cells`` cells per camera grid and cameras at
    ``frame_rates_hz`` (Hz)."""
    batch_s = BATCH_OF_HISTORY * tracker_history_s(max_gap_s)
    batch = sum(rate * batch_s for rate in frame_rates_hz)
    cameras = len(frame_rates_hz) + (len(frame_rates_hz) > 1)  # and the combined grid
    return int(BASE_BYTES + n_cells * BYTES_PER_CELL * cameras
               + batch * BYTES_PER_BATCHED_FRAME)


def memory_refusal(mission: Mission, n_cells: int, limit: tuple[int, str] | None
                   ) -> str | None:
    """Why ``mission`` (``n_cells`` per grid) does not fit ``limit`` (bytes, and what it is;
    None: unknown, then nothing is refused), naming the figures; None when it fits."""
    rates = [c.frame_rate_hz for c in mission.cameras]
    need = estimate_bytes(n_cells, rates, mission.max_gap_s)
    if limit is None or need <= limit[0]:
        return None
    return (f"the daemon would need about {need / 2**20:,.0f} MiB ({n_cells:,} cells per "
            f"grid, {', '.join(f'{r:g}' for r in rates)} frames/s), more than the "
            f"{limit[0] / 2**20:,.0f} MiB of {limit[1]}: lower camera.frame_rate_hz, grow "
            "domain.cell_size_m or give the daemon more memory")


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
