"""``pdcov watch --record DIR``: the exports (report/exports.py) of what the watcher holds,
rewritten in DIR/exports/ while it runs, at most every ``period_s`` and only when something
was received since, and once more at the end.

The coverage is the fleet's merged grid (the vehicles that share one grid) at the origin
of the first of them, outlined at the watcher's thresholds with its target (the largest) as
the gap limit; the detections are every vehicle's candidates (most probable first) and
detections (ground/watcher.py): detections.geojson holds every detection the watcher took,
streamed back from the ``DetectionLog`` (DIR/<vehicle_id>/DETECTION_LOG, a JSON line each,
so memory stays bounded however long the search), the KML the latest in memory
(Watcher.max_detections per vehicle); pdcov.gpx has every vehicle's track as the watcher
holds it (its status positions, ground/watcher.py), without times: the watcher keeps no
real time of a position. Each file is replaced atomically, so a failed write
(a full disk, a folder made read-only) leaves the previous complete file in place: it is
logged once per episode, shown to the operator and tried again at the next period.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.errors import PdcovError
from pdcov.ground.watcher import Watcher
from pdcov.report.exports import (
    Coverage,
    Exported,
    TrackSegment,
    VehicleDetections,
    VehicleTrack,
    write_exports,
)
from pdcov.report.output_extent import drawn_raster, output_extent

log = logging.getLogger("pdcov.watch")
DETECTION_LOG = "pins-detections.jsonl"


class DetectionLog:
    """Every detection the watcher took (ground/watcher.py ``detection_log``), appended as
    one JSON line each to ``folder``/<vehicle_id>/DETECTION_LOG, and read back one at a
    time. Never raises: a failed append is logged once per episode and its detections are
    counted in ``lost`` (the next append starts on a new line, so a torn one is skipped on
    reading)."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.lost = 0
        self.last_error: str | None = None

    def path(self, vehicle_id: str) -> Path:
        return self.folder / vehicle_id / DETECTION_LOG

    def __call__(self, vehicle_id: str, entries: Sequence[dict[str, Any]]) -> None:
        text = "".join(json.dumps(e, allow_nan=False, separators=(",", ":")) + "\n"
                       for e in entries)
        path = self.path(vehicle_id)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(path, "a", encoding="utf-8") as f:
                f.write(("\n" if self.last_error is not None else "") + text)
        except OSError as exc:
            self.lost += len(entries)
            if self.last_error is None:
                log.warning("exports: cannot append detections to %s (%s): "
                            "detections.geojson will lack them", path, exc.strerror or exc)
            self.last_error = f"{path}: {exc.strerror or exc}"
            return
        self.last_error = None

    def entries(self, vehicle_id: str) -> Iterator[dict[str, Any]]:
        """The vehicle's detections in the order taken (none before the first)."""
        path = self.path(vehicle_id)
        if not path.exists():
            return
        with open(path, encoding="utf-8") as f:
            for line in f:
                try:
                    entry = json.loads(line)
                except ValueError:
                    continue  # blank, or torn by a failed append
                if isinstance(entry, dict):
                    yield entry


def coverage_of(watcher: Watcher) -> Coverage | None:
    """The fleet's merged grid as a Coverage, None while no grid (or its origin) is in."""
    merged, ids = watcher.fleet_state()
    if merged is None:
        return None
    origin = watcher.feeds[ids[0]].origin()
    thresholds = watcher.report(0.0).thresholds
    if origin is None or not thresholds:
        return None
    extent = output_extent(merged)  # a county's: the extent flown, drawn in blocks
    drawn = drawn_raster(merged, extent, hidden=False)
    return Coverage(drawn.pd, drawn.mask, drawn.geometry, origin, thresholds,
                    max(watcher.thresholds or thresholds))


def findings_of(watcher: Watcher, detection_log: DetectionLog | None = None
                ) -> list[VehicleDetections]:
    """Every vehicle's candidates (most probable first, then by uid) and detections: the
    latest in memory, and every one from ``detection_log`` when given."""
    return [VehicleDetections(
        vid, tuple(f.detections),
        tuple(sorted(f.candidates.values(), key=lambda c: (-c["p_person"], c["uid"]))),
        None if detection_log is None else partial(detection_log.entries, vid))
        for vid, f in sorted(watcher.feeds.items())]


def tracks_of(watcher: Watcher) -> list[VehicleTrack]:
    """Every vehicle's track (the watcher's status positions: lat, lon, alt m MSL), one
    segment each, without times."""
    return [VehicleTrack(vid, (TrackSegment(
        np.asarray(f.track_lat_lon_alt, dtype=float).reshape(-1, 3)),))
        for vid, f in sorted(watcher.feeds.items()) if f.track_lat_lon_alt]


class ExportRecorder:
    """Writes the exports into ``out`` (created on the first write). Never raises to its
    caller: see the module docstring. ``written``: how many times every file was written;
    ``last``: what the last write wrote and not. ``detection_log``: the log to give the
    Watcher (``Watcher(detection_log=...)``), in ``out``'s parent (the recording folder)."""

    def __init__(self, out: Path, *, period_s: float = 5.0) -> None:
        self.out = Path(out)
        self.detection_log = DetectionLog(self.out.parent)
        self.period_s = period_s
        self.written = 0
        self.write_errors = 0
        self.last_error: str | None = None
        self.last: Exported | None = None
        self._version: int | None = None
        self._next_s = float("-inf")

    @property
    def warning(self) -> str | None:
        """The line the views show while the exports cannot be written or detections were
        lost, else None."""
        lost = self.detection_log.lost
        lines = [f"exports in {self.out}: failing ({self.last_error}); retrying"
                 if self.last_error is not None else "",
                 f"{lost} detections could not be logged, so detections.geojson lacks them "
                 f"({self.detection_log.last_error or 'logging again'})" if lost else ""]
        return "; ".join(x for x in lines if x) or None

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
            self.last = write_exports(self.out, coverage_of(watcher),
                                      findings_of(watcher, self.detection_log),
                                      title=f"pdcov watch: {names}",
                                      tracks=tracks_of(watcher))
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
