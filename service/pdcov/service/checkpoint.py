"""Checkpoints: the grid and what is needed to continue it, written tile by tile.

A checkpoint is a folder (``CHECKPOINT_NAME`` in the state dir) of two slots, ``a`` and
``b``, and ``current``, a file naming the complete one. Each slot holds ``grid.zarr`` (the
grid's Zarr v3 store, core/grid_store.py), with a cameras list ``cameras/<name>.zarr``
(each camera's own grid), ``meta.json`` (the mission hash, the vehicle id, the frame
lattice's anchor, the last frame time, the autopilot clock's offset and boot time, the
tiles sequence number and counters: checkpoint_meta.py) and ``candidates.json``
(service/candidate_store.py). A checkpoint is written into the slot ``current`` does not
name, holding only the tiles changed since that slot was last written (the whole grid the
first time a slot is written in a run), then ``current`` is renamed over to name it: a
kill -9 or a power loss at any moment leaves the previous checkpoint or the new one, never
a mixture. Taking a checkpoint copies nothing on the daemon's loop
(``CheckpointWriter.prepare``): a changed tile is copied when the loop next writes it or when
``CheckpointJob.write``, off the loop, takes it (core/tiles.FrozenTiles).

A checkpoint.npz of an earlier pdcov (one zip file) is set aside, not resumed.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pdcov.atomic import atomic_write
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_store import StoreUpdate, frozen_update, read_store_like, write_update
from pdcov.errors import InputFileError, PdcovError
from pdcov.service.checkpoint_meta import META_VERSION, CheckpointMeta

CHECKPOINT_NAME = "checkpoint"
LEGACY_NAME = "checkpoint.npz"
CURRENT = "current"
SLOTS = ("a", "b")
META_FILE = "meta.json"
CANDIDATES_FILE = "candidates.json"
GRID_STORE = "grid.zarr"
MAX_JSON_BYTES = 64 << 20
"""Largest meta.json or candidates.json read (the candidates are bounded far below it)."""


@dataclass(frozen=True, slots=True)
class Resumed:
    """The outcome of looking for a checkpoint: the grid to continue (None: start fresh),
    its metadata (None with it), and what was done, in words (the daemon logs it). With a
    grid: ``candidates``, the candidates member's parsed JSON (None: a checkpoint without
    one, older), or ``candidates_error``, why that member cannot be read (the grid is
    resumed all the same)."""

    grid: CoverageGrid | None
    meta: CheckpointMeta | None
    message: str
    set_aside: Path | None = None
    cameras: dict[str, CoverageGrid] | None = None  # a cameras list: each camera's grid
    candidates: Any = None
    candidates_error: str | None = None


def camera_store(name: str) -> str:
    """Camera ``name``'s own grid in a slot (a cameras list)."""
    return f"cameras/{name}.zarr"


@dataclass(frozen=True, slots=True, eq=False)
class CheckpointJob:
    """One checkpoint, copied from the grids (``CheckpointWriter.prepare``), to be written
    (``write``) into ``slot`` of ``path``: each store's update by its place in the slot,
    the metadata and candidates' documents, and ``fresh``: the slot is cleared first (its
    first write in this run). ``meta``: the metadata, for the core when written (None:
    a mapping written as it is, by a test)."""

    path: Path
    slot: str
    fresh: bool
    stores: dict[str, StoreUpdate]
    meta: CheckpointMeta | None
    doc: dict[str, Any]
    candidates: Mapping[str, Any] | None
    versions: dict[str, int]

    def write(self) -> None:
        """The slot written, then ``current`` renamed to name it; OSError or OutputError
        (the previous checkpoint stays current)."""
        slot = self.path / self.slot
        if self.fresh and slot.exists():
            shutil.rmtree(slot)
        slot.mkdir(parents=True, exist_ok=True)
        for place, update in self.stores.items():
            write_update(slot / place, update)
        with atomic_write(slot / META_FILE, "w") as fh:
            json.dump(self.doc, fh)
        if self.candidates is not None:
            with atomic_write(slot / CANDIDATES_FILE, "w") as fh:
                json.dump(self.candidates, fh, allow_nan=False)
        else:
            (slot / CANDIDATES_FILE).unlink(missing_ok=True)
        os.sync()  # the stores' chunks on disk before ``current`` names them
        with atomic_write(self.path / CURRENT, "w") as fh:
            fh.write(self.slot)

    def release(self) -> None:
        """Written or failed: the grids' tiles are no longer owed to it (on the grids'
        thread)."""
        for update in self.stores.values():
            update.release()


class CheckpointWriter:
    """Checkpoints into the folder ``path``, each slot holding the tiles changed since it
    was last written by this writer (everything the first time)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        # Per slot, per store in it, the grid's clock when the slot last completed a write.
        self._written: dict[str, dict[str, int]] = {}

    def prepare(self, grid: CoverageGrid, meta: CheckpointMeta | Mapping[str, Any],
                cameras: Mapping[str, CoverageGrid] | None = None,
                candidates: Mapping[str, Any] | None = None) -> CheckpointJob:
        """The checkpoint of ``grid`` (and each camera's own grid, ``cameras``, by name)
        now, with ``meta`` (a mapping is written as it is, with the format version: tests
        write damaged metadata so) and ``candidates`` (candidate_store.checkpoint_doc):
        the changed tiles copied, nothing written."""
        slot = self._next_slot()
        written = self._written.get(slot)
        grids = {GRID_STORE: grid, **{camera_store(n): g for n, g in (cameras or {}).items()}}
        stores = {place: frozen_update(g, None if written is None
                                       else g.tile_keys(since=written.get(place, 0)))
                  for place, g in grids.items()}
        doc = meta.to_json() if isinstance(meta, CheckpointMeta) else {
            "version": META_VERSION, **meta}
        parsed = meta if isinstance(meta, CheckpointMeta) else None
        return CheckpointJob(self.path, slot, written is None, stores, parsed, doc,
                             candidates, {p: g.clock.now for p, g in grids.items()})

    def written(self, job: CheckpointJob) -> None:
        """``job`` was written: its slot holds its grids as they were when prepared."""
        self._written[job.slot] = job.versions

    def _next_slot(self) -> str:
        """The slot ``current`` does not name."""
        try:
            current = (self.path / CURRENT).read_text().strip()
        except OSError:
            current = SLOTS[1]
        return SLOTS[0] if current != SLOTS[0] else SLOTS[1]


def write_checkpoint(path: Path, grid: CoverageGrid,
                     meta: CheckpointMeta | Mapping[str, Any],
                     cameras: Mapping[str, CoverageGrid] | None = None,
                     candidates: Mapping[str, Any] | None = None) -> None:
    """One whole checkpoint written now into the folder ``path`` (``CheckpointWriter``'s
    prepare and write; tools and tests)."""
    writer = CheckpointWriter(path)
    job = writer.prepare(grid, meta, cameras, candidates)
    try:
        job.write()
    finally:
        job.release()


def current_slot(path: Path) -> Path:
    """The slot ``current`` names in the checkpoint folder ``path``; InputFileError when
    there is none."""
    try:
        name = (path / CURRENT).read_text(errors="replace")[:8].strip()
    except OSError as exc:
        raise InputFileError(f"{path}: not a pdcov checkpoint (no {CURRENT}: "
                             f"{exc.strerror})") from None
    if name not in SLOTS:
        raise InputFileError(f"{path}: not a pdcov checkpoint ({CURRENT} names {name!r}, "
                             f"expected {' or '.join(SLOTS)})")
    return path / name


def read_meta(path: Path) -> dict[str, Any]:
    """The metadata of the checkpoint folder ``path`` as its JSON object (for tools and
    tests), checked as ``read_checkpoint_meta`` does."""
    slot = current_slot(path)
    doc = _read_json(slot / META_FILE)
    CheckpointMeta.from_json(slot / META_FILE, doc)
    return doc  # type: ignore[no-any-return]


def read_checkpoint_meta(path: Path) -> CheckpointMeta:
    """The metadata of the checkpoint folder ``path``; InputFileError when it has none or
    is corrupt (the fields the daemon resumes from must have the types it wrote: a
    damaged or foreign checkpoint is set aside, never half used)."""
    slot = current_slot(path)
    return CheckpointMeta.from_json(slot / META_FILE, _read_json(slot / META_FILE))


def _read_json(path: Path) -> Any:
    """A JSON file's parsed document, at most MAX_JSON_BYTES; InputFileError naming it."""
    def error(why: str) -> InputFileError:
        return InputFileError(f"{path}: not a pdcov checkpoint ({why})")

    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_JSON_BYTES + 1)
    except OSError as exc:
        raise error(exc.strerror or str(exc)) from None
    if len(data) > MAX_JSON_BYTES:
        raise error(f"over {MAX_JSON_BYTES} bytes")
    try:
        return json.loads(data)
    except (ValueError, RecursionError) as exc:  # RecursionError: JSON nested too deep
        raise error(f"{type(exc).__name__}: {exc}") from None


def resume(state_dir: Path, mission_hash: str, new_grid: CoverageGrid,
           new_cameras: Mapping[str, CoverageGrid] | None = None) -> Resumed:
    """The checkpoint in ``state_dir`` if it belongs to this mission and vehicle (same
    hash); otherwise (another mission or vehicle, unreadable, or an earlier pdcov's
    checkpoint.npz) it is renamed aside with a time stamp and the daemon starts fresh.
    ``new_cameras``: with a cameras list, each camera's new grid (by name), whose grids the
    checkpoint must hold too."""
    path = state_dir / CHECKPOINT_NAME
    legacy = state_dir / LEGACY_NAME
    stamp = time.strftime("%Y%m%dT%H%M%S")
    if legacy.exists():
        aside = legacy.with_name(f"checkpoint-{stamp}.set-aside.npz")
        legacy.replace(aside)
        if not path.exists():
            return Resumed(None, None, f"checkpoint {legacy} set aside as {aside.name}: "
                                       "written by an earlier pdcov (one .npz file, its grid "
                                       "a grid.npz); starting a new grid", aside)
    # A kill while ``current`` was renamed over leaves atomic_write's temporary file: never
    # read, removed here.
    for stale in path.glob(f".{CURRENT}.*.tmp"):
        stale.unlink(missing_ok=True)
    if not path.exists():
        return Resumed(None, None, f"no checkpoint in {state_dir}: starting a new grid")
    try:
        meta = read_checkpoint_meta(path)
        slot = current_slot(path)
        if meta.mission_hash != mission_hash:
            vehicle = meta.vehicle_id
            why = (f"it was written for vehicle "
                   f"{'(not recorded)' if vehicle is None else repr(vehicle)} with mission "
                   f"hash {meta.mission_hash}, this daemon's is {mission_hash} (the "
                   "vehicle id, domain, camera, detector or grid settings differ)")
        else:
            grid = read_store_like(slot / GRID_STORE, new_grid)
            cameras = {name: read_store_like(slot / camera_store(name), g)
                       for name, g in (new_cameras or {}).items()}
            if any(g.geometry != new_grid.geometry or not g.free.same_as(new_grid.free)
                   for g in (grid, *cameras.values())):
                why = "its grid geometry differs from this mission's"
            else:
                return Resumed(grid, meta, f"resumed from {slot}: {grid.frames} frames, "
                                           f"last frame at t = {meta.last_frame_t_s} s",
                               cameras=cameras or None, **_candidates(slot))
    except PdcovError as exc:  # InputFileError, or a DomainError from its geometry
        why = f"it cannot be read ({exc})"
    aside = path.with_name(f"checkpoint-{stamp}.set-aside")
    path.replace(aside)
    return Resumed(None, None, f"checkpoint {path} set aside as {aside.name}: {why}; "
                             "starting a new grid", aside)


def _candidates(slot: Path) -> dict[str, Any]:
    """Resumed's ``candidates`` (absent: no such file) or ``candidates_error``."""
    if not (slot / CANDIDATES_FILE).exists():
        return {}
    try:
        return {"candidates": _read_json(slot / CANDIDATES_FILE)}
    except InputFileError as exc:
        return {"candidates_error": str(exc)}
