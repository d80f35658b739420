"""``pdcov watch --record DIR``: what the watcher received, and at the end its grids.

Layout (docs/ground-station.md):

    DIR/<vehicle_id>/status.jsonl   one line per status: {"recv_unix_s": t, "status": {...}}
    DIR/<vehicle_id>/tiles.bin      records: recv_unix_s f64, length u32 (little-endian),
                                    then the tiles payload as received (docs/protocol.md)
    DIR/<vehicle_id>/snapshot-N.npz each snapshot reply as received
    DIR/<vehicle_id>/mission-N.json each mission reply as received
    DIR/<vehicle_id>/grid.npz       at the end: the grid the watcher rebuilt
    DIR/fleet/                      at the end: the merged grid.npz and, with the mission
                                    config, the report (metrics.json, heatmap.png, ...)
"""

from __future__ import annotations

import io
import json
import struct
import time
from pathlib import Path
from typing import IO, Any

import numpy as np

from pdcov.atomic import atomic_write, write_text_atomic
from pdcov.bus.grid_state import GridState, grid_hash
from pdcov.config import Mission
from pdcov.core.grid import SNAPSHOT_VERSION
from pdcov.errors import PdcovError
from pdcov.ground.watcher import Watcher

TILE_RECORD = struct.Struct("<dI")


def write_state_npz(path: Path, state: GridState) -> None:
    """A grid.npz of ``state`` with the arrays CoverageGrid.save_npz writes (no revisit
    clock: a watcher does not receive one)."""
    buf = io.BytesIO()
    g = state.geometry
    pd = 0.0 - np.expm1(state.log_miss_d.astype(np.float64))
    pfa = 0.0 - np.expm1(state.log_miss_fa.astype(np.float64))
    np.savez_compressed(buf, version=SNAPSHOT_VERSION, pd=pd, pfa=pfa, n_obs=state.n_obs,
                        mask=state.mask, log_miss_d=state.log_miss_d,
                        log_miss_fa=state.log_miss_fa, x0_m=g.x0_m, y0_m=g.y0_m,
                        cell_size_m=g.cell_size_m, frames=state.frames)
    with atomic_write(path, "wb") as fh:
        fh.write(buf.getvalue())


class Recording:
    """Appends what is received under ``out``; call ``close`` (then ``finish``) at the end."""

    def __init__(self, out: Path) -> None:
        self.out = Path(out)
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            used = any(self.out.iterdir())
        except OSError as exc:
            raise PdcovError(f"--record {out}: cannot create the folder "
                             f"({exc.strerror or exc})") from None
        if used:  # appending to another run's files would mix two recordings
            raise PdcovError(f"--record {out}: the folder is not empty; give a new one")
        self._files: dict[tuple[str, str], IO[Any]] = {}
        self._replies: dict[tuple[str, str], int] = {}

    def _file(self, vid: str, name: str, mode: str) -> IO[Any]:
        f = self._files.get((vid, name))
        if f is None:
            (self.out / vid).mkdir(exist_ok=True)
            f = self._files[(vid, name)] = open(self.out / vid / name, mode)  # noqa: SIM115
        return f

    def __call__(self, vehicle_id: str, kind: str, payload: bytes) -> None:
        t = time.time()
        if kind == "status":
            try:
                doc: Any = json.loads(payload.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError):
                doc = payload.decode("utf-8", "replace")
            f = self._file(vehicle_id, "status.jsonl", "a")
            f.write(json.dumps({"recv_unix_s": t, "status": doc}) + "\n")
            f.flush()
        elif kind == "tiles":
            f = self._file(vehicle_id, "tiles.bin", "ab")
            f.write(TILE_RECORD.pack(t, len(payload)) + payload)
            f.flush()
        elif kind in ("snapshot", "mission"):
            n = self._replies.get((vehicle_id, kind), 0) + 1
            self._replies[(vehicle_id, kind)] = n
            (self.out / vehicle_id).mkdir(exist_ok=True)
            ext = "npz" if kind == "snapshot" else "json"
            (self.out / vehicle_id / f"{kind}-{n}.{ext}").write_bytes(payload)

    def close(self) -> None:
        for f in self._files.values():
            f.close()
        self._files.clear()

    def finish(self, watcher: Watcher, mission: Mission | None) -> list[str]:
        """Write each vehicle's rebuilt grid and the fleet's grid and report; returns lines
        saying what was written."""
        lines = []
        for vid, feed in sorted(watcher.feeds.items()):
            if feed.state is not None:
                (self.out / vid).mkdir(exist_ok=True)
                write_state_npz(self.out / vid / "grid.npz", feed.state)
        merged, ids = watcher.fleet_state()
        if merged is None:
            return [f"record: {self.out}: no grid was received"]
        fleet = self.out / "fleet"
        fleet.mkdir(exist_ok=True)
        grid = mission.new_grid() if mission is not None else None
        if mission is not None and grid is not None \
                and grid_hash(grid.geometry, grid.mask) == merged.hash:
            from pdcov.report.outputs import summary_text, write_outputs

            grid.log_miss_d[:] = merged.log_miss_d
            grid.log_miss_fa[:] = merged.log_miss_fa
            grid.n_obs[:] = merged.n_obs
            grid.frames = merged.frames
            track = _track_enu(watcher, ids, mission) if len(ids) == 1 else None
            run = write_outputs(fleet, mission, grid, mission.origin(),
                                title=f"pdcov watch: {', '.join(ids)}", track_enu=track,
                                extra_metrics={"vehicles": list(ids)})
            lines.append(summary_text(run))
        else:
            write_state_npz(fleet / "grid.npz", merged)
            doc = {"vehicles": list(ids), "frames": merged.frames,
                   "proportion_at_or_above": {
                       str(t): merged.proportion_at_or_above(t)
                       for t in watcher.report(0.0).thresholds}}
            write_text_atomic(fleet / "metrics.json", json.dumps(doc, indent=2) + "\n")
            why = ("no --config" if mission is None
                   else "the mission config's grid is not the vehicles' grid")
            lines.append(f"wrote grid.npz and metrics.json in {fleet} (figures need the "
                         f"mission config: {why})")
        return lines


def _track_enu(watcher: Watcher, ids: tuple[str, ...], mission: Mission) -> np.ndarray | None:
    from pdcov.core.geodesy import geodetic_to_enu

    pts = watcher.feeds[ids[0]].track_lat_lon_alt
    if len(pts) < 2:
        return None
    a = np.asarray(pts, dtype=float)
    return geodetic_to_enu(a[:, 0], a[:, 1], a[:, 2], mission.origin())
