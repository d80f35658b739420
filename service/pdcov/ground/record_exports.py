"""``pdcov watch --record DIR``: the exports (report/exports.py) of what the watcher holds,
rewritten in DIR/exports/ while it runs, at most every ``period_s`` and only when something
was received since, and once more at the end.

The coverage is the fleet's merged grid (the vehicles that share one grid) at the origin
of the first of them, outlined at the watcher's thresholds with its target (the largest) as
the gap limit; the detections are every vehicle's candidates and recent detections
(ground/watcher.py). Each file is replaced atomically, so a failed write (a full disk, a
folder made read-only) leaves the previous complete file in place: it is logged once per
episode, shown to the operator and tried again at the next period.
"""

from __future__ import annotations

import logging
from pathlib import Path

from pdcov.errors import PdcovError
from pdcov.ground.watcher import Watcher
from pdcov.report.exports import Coverage, Exported, VehicleDetections, write_exports

log = logging.getLogger("pdcov.watch")


def coverage_of(watcher: Watcher) -> Coverage | None:
    """The fleet's merged grid as a Coverage, None while no grid (or its origin) is in."""
    merged, ids = watcher.fleet_state()
    if merged is None:
        return None
    origin = watcher.feeds[ids[0]].origin()
    thresholds = watcher.report(0.0).thresholds
    if origin is None or not thresholds:
        return None
    return Coverage(merged.pd, merged.mask, merged.geometry, origin, thresholds,
                    max(watcher.thresholds or thresholds))


def findings_of(watcher: Watcher) -> list[VehicleDetections]:
    """Every vehicle's candidates (by id) and recent detections."""
    return [VehicleDetections(vid, tuple(f.detections),
                              tuple(c for _, c in sorted(f.candidates.items())))
            for vid, f in sorted(watcher.feeds.items())]


class ExportRecorder:
    """Writes the exports into ``out`` (created on the first write). Never raises to its
    caller: see the module docstring. ``written``: how many times every file was written;
    ``last``: what the last write wrote and not."""

    def __init__(self, out: Path, *, period_s: float = 5.0) -> None:
        self.out = Path(out)
        self.period_s = period_s
        self.written = 0
        self.write_errors = 0
        self.last_error: str | None = None
        self.last: Exported | None = None
        self._version: int | None = None
        self._next_s = float("-inf")

    @property
    def warning(self) -> str | None:
        """The line the views show while the exports cannot be written, else None."""
        if self.last_error is None:
            return None
        return f"exports in {self.out}: failing ({self.last_error}); retrying"

    def poll(self, watcher: Watcher, version: int, now_s: float) -> bool:
        """Write when ``version`` (the shell's input count) changed since the last write
        and ``period_s`` has passed since the last attempt; True when written now."""
        if version == self._version or now_s < self._next_s:
            return False
        self._next_s = now_s + self.period_s
        if self.write(watcher):
            self._version = version
            return True
        return False

    def write(self, watcher: Watcher) -> bool:
        """Write every export now; False (logged once per episode) when one failed."""
        names = ", ".join(sorted(watcher.feeds)) or "no vehicle yet"
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            self.last = write_exports(self.out, coverage_of(watcher), findings_of(watcher),
                                      title=f"pdcov watch: {names}")
        except (PdcovError, OSError) as exc:  # OutputError names the file
            self.write_errors += 1
            if self.last_error is None:
                log.warning("exports: %s; the previous files stay, retrying every %g s",
                            exc, self.period_s)
            self.last_error = str(exc)
            return False
        if self.last_error is not None:
            log.warning("exports: writing again in %s (%d failed attempts)", self.out,
                        self.write_errors)
            self.last_error = None
        self.written += 1
        return True
