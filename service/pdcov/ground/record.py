"""``pdcov watch --record DIR``: what the watcher received, and at the end its grids.

Layout (docs/ground-station.md):

    DIR/<vehicle_id>/status.jsonl   one line per status: {"recv_unix_s": t, "status": {...}}
    DIR/<vehicle_id>/tiles.bin      records: recv_unix_s f64, length u32 (little-endian),
                                    then the tiles payload as received (docs/protocol.md)
    DIR/<vehicle_id>/snapshot-N.npz each snapshot reply as received
    DIR/<vehicle_id>/mission-N.json each mission reply as received
    DIR/<vehicle_id>/detections.jsonl one line per detections payload:
                                    {"recv_unix_s": t, "detections": {...}}
    DIR/<vehicle_id>/candidates-N.json each candidates reply as received
    DIR/<vehicle_id>/pins-detections.jsonl every detection taken, a JSON line each
                                    (ground/record_exports.py DetectionLog)
    DIR/exports/                    while running and at the end: ground/record_exports.py
    DIR/<vehicle_id>/grid.npz       at the end: the grid the watcher rebuilt (grid.zarr,
                                    the grid store of its tiles, above 64 Mi cells)
    DIR/fleet/                      at the end: the merged grid (the same way) and, with
                                    the mission config, a whole run folder: metrics.json,
                                    figures, exports, report.html and report.pdf
"""

from __future__ import annotations

import io
import json
import logging
import os
import struct
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pdcov.atomic import atomic_write, write_text_atomic
from pdcov.bus.grid_state import GridState, grid_hash
from pdcov.config.mission import Mission
from pdcov.core.grid_layer import Layer
from pdcov.core.grid_snapshot import SNAPSHOT_VERSION
from pdcov.core.grid_store import write_update
from pdcov.core.looks import LooksConfig
from pdcov.core.tiles import MAX_DENSE_CELLS
from pdcov.errors import PdcovError
from pdcov.ground.record_exports import tracks_of
from pdcov.ground.watcher import Watcher
from pdcov.report.exports import VehicleDetections, tracks_enu

TILE_RECORD = struct.Struct("<dI")
LIMITING_NOT_SENT = "not sent by the vehicle (pdcov before tiles v2)"
"""The report's limiting factor when a vehicle's daemon sends tiles version 1."""
MAX_BACKLOG_BYTES = 64 << 20
"""Most bytes of received payloads kept while the disk refuses them (Recording)."""

log = logging.getLogger("pdcov.watch")


def _json_line(t: float, kind: str, payload: bytes) -> bytes:
    """The <kind>.jsonl line of a status or detections payload: its JSON object under
    ``kind``, or (not strict JSON: not UTF-8, not JSON, a NaN or infinity in it) its text as
    a string, so every line stays JSON."""
    text = payload.decode("utf-8", "replace")
    try:
        line = json.dumps({"recv_unix_s": t, kind: json.loads(text)}, allow_nan=False)
    except (ValueError, RecursionError):
        line = json.dumps({"recv_unix_s": t, kind: text})
    return (line + "\n").encode()


def write_state_grid(folder: Path, state: GridState) -> str:
    """Write ``state`` into ``folder`` as grid.npz (``write_state_npz``) or, above
    MAX_DENSE_CELLS cells, as grid.zarr (its tiles, core/grid_store.py); returns the name
    written."""
    g = state.geometry
    if g.n_rows * g.n_cols <= MAX_DENSE_CELLS:
        write_state_npz(folder / "grid.npz", state)
        return "grid.npz"
    write_update(folder / "grid.zarr", state.store_update())
    return "grid.zarr"


def write_state_npz(path: Path, state: GridState) -> None:
    """A grid.npz of ``state`` with the arrays CoverageGrid.save_npz writes (no revisit
    clock: a watcher does not receive one; no limiting when the state's is unknown)."""
    buf = io.BytesIO()
    g = state.geometry
    pd = 0.0 - np.expm1(state.log_miss_d.astype(np.float64))
    pfa = 0.0 - np.expm1(state.log_miss_fa.astype(np.float64))
    limiting = {} if state.limiting is None else {"limiting": state.limiting}
    np.savez_compressed(buf, version=SNAPSHOT_VERSION, pd=pd, pfa=pfa, n_obs=state.n_obs,
                        mask=state.mask, log_miss_d=state.log_miss_d,
                        log_miss_fa=state.log_miss_fa, x0_m=g.x0_m, y0_m=g.y0_m,
                        cell_size_m=g.cell_size_m, frames=state.frames,
                        **limiting)  # type: ignore[arg-type]  # **limiting to allow_pickle
    with atomic_write(path, "wb") as fh:
        fh.write(buf.getvalue())


@dataclass(slots=True)
class _Pending:
    """A payload's bytes waiting to be written: appended to ``path`` (status.jsonl,
    tiles.bin; ``done`` bytes already are) or written as the whole file (replies)."""

    path: Path
    data: bytes
    append: bool
    done: int = 0


class Recording:
    """Appends what is received under ``out``; call ``close`` (then ``finish``) at the end.

    Never raises to its caller once made: a write that fails (a full disk, EIO) is logged
    once per episode and counted, its payload and those after it wait in order in a
    backlog of at most ``max_backlog_bytes`` and are written at the next call (or
    ``flush``); once it is full, what arrives is dropped and counted until it is written.
    What the views may show: ``write_errors`` (failed attempts), ``last_error`` (the
    current episode's, None while writing works), ``pending`` (payloads waiting),
    ``dropped`` (never recorded).
    ``write``: os.write, or a stand-in for tests (same contract: bytes written, or
    OSError)."""

    def __init__(self, out: Path, *, max_backlog_bytes: int = MAX_BACKLOG_BYTES,
                 write: Callable[[int, memoryview], int] = os.write) -> None:
        self.out = Path(out)
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            used = any(self.out.iterdir())
        except OSError as exc:
            raise PdcovError(f"--record {out}: cannot create the folder "
                             f"({exc.strerror or exc})") from None
        if used:  # appending to another run's files would mix two recordings
            raise PdcovError(f"--record {out}: the folder is not empty; give a new one")
        self.max_backlog_bytes = max_backlog_bytes
        self._write = write
        self._fds: dict[Path, int] = {}
        self._replies: dict[tuple[str, str], int] = {}
        self._backlog: deque[_Pending] = deque()
        self._backlog_bytes = 0
        self._overflowing = False
        self.write_errors = 0
        self.dropped = 0
        self.last_error: str | None = None

    @property
    def pending(self) -> int:
        """Payloads received but not yet written."""
        return len(self._backlog)

    @property
    def warning(self) -> str | None:
        """The line the views show while writing fails or once payloads were lost, else
        None."""
        if self.last_error is None and not self.dropped:
            return None
        state = (f"failing ({self.last_error}), {self.pending} payloads waiting"
                 if self.last_error is not None else "writing again")
        lost = f", {self.dropped} payloads not recorded" if self.dropped else ""
        return f"recording in {self.out}: {state}{lost}"

    def __call__(self, vehicle_id: str, kind: str, payload: bytes) -> None:
        item = self._item(vehicle_id, kind, bytes(payload), time.time())
        if item is None:
            return
        if self._overflowing or (self._backlog and self._backlog_bytes + len(item.data)
                                 > self.max_backlog_bytes):
            # Full: drop what arrives until the backlog is written, so that the files hold
            # what came in order up to the first drop, with no hole before it.
            self._overflowing = True
            self.dropped += 1
        else:
            self._backlog.append(item)
            self._backlog_bytes += len(item.data)
        self.flush()

    def _item(self, vid: str, kind: str, payload: bytes, t: float) -> _Pending | None:
        folder = self.out / vid
        if kind in ("status", "detections"):
            return _Pending(folder / f"{kind}.jsonl", _json_line(t, kind, payload),
                            append=True)
        if kind == "tiles":
            return _Pending(folder / "tiles.bin", TILE_RECORD.pack(t, len(payload)) + payload,
                            append=True)
        if kind in ("snapshot", "mission", "candidates"):
            n = self._replies[(vid, kind)] = self._replies.get((vid, kind), 0) + 1
            ext = "npz" if kind == "snapshot" else "json"
            return _Pending(folder / f"{kind}-{n}.{ext}", payload, append=False)
        return None

    def flush(self) -> bool:
        """Write the backlog in order, stopping at the first failure (kept for the next
        try); True when nothing is left."""
        while self._backlog:
            item = self._backlog[0]
            try:
                self._put(item)
            except OSError as exc:
                self.write_errors += 1
                if self.last_error is None:
                    log.warning("record: cannot write %s (%s); keeping up to %d bytes of "
                                "what arrives and retrying", item.path,
                                exc.strerror or exc, self.max_backlog_bytes)
                self.last_error = f"{item.path}: {exc.strerror or exc}"
                return False
            self._backlog.popleft()
            self._backlog_bytes -= len(item.data)
        self._overflowing = False
        if self.last_error is not None:
            log.warning("record: writing again (%d failed attempts, %d payloads dropped so "
                        "far)", self.write_errors, self.dropped)
            self.last_error = None
        return True

    def _put(self, item: _Pending) -> None:
        """Write what is left of ``item``; a partial write advances ``item.done`` (an
        append never repeats bytes), a whole file starts again at the next try."""
        item.path.parent.mkdir(exist_ok=True)
        if item.append:
            fd = self._fds.get(item.path)
            if fd is None:
                fd = self._fds[item.path] = os.open(
                    item.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
            self._write_all(fd, item)
            return
        item.done = 0
        fd = os.open(item.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            self._write_all(fd, item)
        finally:
            os.close(fd)

    def _write_all(self, fd: int, item: _Pending) -> None:
        view = memoryview(item.data)
        while item.done < len(view):
            item.done += self._write(fd, view[item.done:])

    def close(self) -> None:
        """A last try at the backlog, then the files are closed; what could not be written
        is logged (and stays counted in ``pending``)."""
        if not self.flush():
            log.warning("record: %d payloads (%d bytes) could not be written: %s",
                        self.pending, self._backlog_bytes, self.last_error)
        for fd in self._fds.values():
            try:
                os.close(fd)
            except OSError as exc:  # a deferred write error (NFS): the data may be lost
                self.write_errors += 1
                self.last_error = f"closing a file: {exc.strerror or exc}"
        self._fds.clear()

    def finish(self, watcher: Watcher, mission: Mission | None,
               findings: Sequence[VehicleDetections] | None = None) -> list[str]:
        """Write each vehicle's rebuilt grid and the fleet's grid, outputs and handover
        report (with ``findings``, the exports of their detections); returns lines saying
        what was written, and what could not be (a write error is one of them, never
        raised)."""
        lines = []
        if self.pending or self.dropped:
            lines.append(f"record: {self.pending + self.dropped} received payloads are not "
                         f"in {self.out} ({self.dropped} dropped while the disk refused "
                         f"writes; last error: {self.last_error or 'none now'})")
        try:
            return lines + self._finish(watcher, mission, findings)
        except OSError as exc:
            return lines + [f"record: could not write the final grids in {self.out}: "
                            f"{exc.strerror or exc}"]

    def _finish(self, watcher: Watcher, mission: Mission | None,
                findings: Sequence[VehicleDetections] | None) -> list[str]:
        lines = []
        for vid, feed in sorted(watcher.feeds.items()):
            if feed.state is not None:
                (self.out / vid).mkdir(exist_ok=True)
                write_state_grid(self.out / vid, feed.state)
        merged, ids = watcher.fleet_state()
        if merged is None:
            return [f"record: {self.out}: no grid was received"]
        fleet = self.out / "fleet"
        fleet.mkdir(exist_ok=True)
        # The fleet's state is the vehicles' derived log-misses added: an independent-looks
        # grid holds it (a correlated one would write zero counts beside it).
        grid = replace(mission, looks=LooksConfig()).new_mission_grid() if mission is not None \
            else None
        if mission is not None and grid is not None \
                and grid_hash(grid.geometry, grid.free) == merged.hash:
            from pdcov.report.handover import with_report
            from pdcov.report.outputs import summary_text, write_outputs

            for window in merged.written_windows():  # tile by tile: a county's too
                for layer in (Layer.LOG_MISS_D, Layer.LOG_MISS_FA, Layer.N_OBS,
                              Layer.LIMITING):
                    if layer is not Layer.LIMITING or merged.limiting_known:
                        grid.layer(layer).write(window, merged.read(layer, window))
            grid.frames = merged.frames
            tracks = [t for t in tracks_of(watcher) if t.vehicle in ids]
            run = write_outputs(fleet, mission, grid, mission.origin(),
                                title=f"pdcov watch: {', '.join(ids)}",
                                track_enu=tracks_enu(tracks, mission.origin()),
                                tracks=tracks, extra_metrics={"vehicles": list(ids)},
                                limiting_unknown=None if merged.limiting_known
                                else LIMITING_NOT_SENT, exports=findings)
            lines.append(summary_text(with_report(run)))
        else:
            name = write_state_grid(fleet, merged)
            doc = {"vehicles": list(ids), "frames": merged.frames,
                   "proportion_at_or_above": {
                       str(t): share for t, share in merged.proportions_at_or_above(
                           watcher.report(0.0).thresholds).items()},
                   "limiting_cells": merged.limiting_counts() if merged.limiting_known
                   else None}
            if not merged.limiting_known:
                doc["limiting_unknown"] = LIMITING_NOT_SENT
            write_text_atomic(fleet / "metrics.json", json.dumps(doc, indent=2) + "\n")
            why = ("no --config" if mission is None
                   else "the mission config's grid is not the vehicles' grid")
            lines.append(f"wrote {name} and metrics.json in {fleet} (figures need the "
                         f"mission config: {why})")
        return lines
