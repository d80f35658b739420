"""Checkpoints: the grid and what is needed to continue it, in one atomically written file.

The file is the grid.npz that ``CoverageGrid.save_npz`` writes (``pdcov evaluate`` and
``np.load`` read it as it is) with one more zip member, ``pdcov_checkpoint.json``: the
mission hash (settings.mission_hash: the vehicle id is part of it) and the vehicle id (named
when a checkpoint is set aside), the frame lattice's anchor ``t0_s`` and the last
frame time (autopilot clock, s), the autopilot clock's offset and boot time (so that a
restarted daemon continues the clock), the tiles sequence number and counters; and
``pdcov_candidates.json``, the candidates (service/candidate_store.py). It is
written to a temporary file, fsynced and renamed (atomic.atomic_write): a kill -9 at any
moment leaves the previous checkpoint or the new one, never a torn file.
"""

from __future__ import annotations

import io
import json
import time
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pdcov.atomic import atomic_write
from pdcov.core.grid import CoverageGrid
from pdcov.errors import InputFileError, PdcovError
from pdcov.npz_file import DAMAGED, read_zip_member
from pdcov.service.checkpoint_meta import META_VERSION, CheckpointMeta

META_MEMBER = "pdcov_checkpoint.json"
CANDIDATES_MEMBER = "pdcov_candidates.json"
CHECKPOINT_NAME = "checkpoint.npz"


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


def camera_member(name: str) -> str:
    """The zip member holding camera ``name``'s own grid (a cameras list)."""
    return f"pdcov_camera_{name}.npz"


def write_checkpoint(path: Path, grid: CoverageGrid,
                     meta: CheckpointMeta | Mapping[str, Any],
                     cameras: Mapping[str, CoverageGrid] | None = None,
                     candidates: Mapping[str, Any] | None = None) -> None:
    """Write the grid and ``meta`` atomically to ``path`` (a mapping is written as it is,
    with the format version: tests write damaged metadata so); with a cameras list, each
    camera's own grid too (``cameras``, by name: one more member each, the snapshot
    ``save_npz`` writes); ``candidates``: the candidates' document
    (candidate_store.checkpoint_doc), in the same write."""
    doc = meta.to_json() if isinstance(meta, CheckpointMeta) else {"version": META_VERSION,
                                                                   **meta}
    buf = io.BytesIO()
    grid.write_npz(buf)
    with zipfile.ZipFile(buf, "a") as zf:
        zf.writestr(META_MEMBER, json.dumps(doc))
        if candidates is not None:
            zf.writestr(CANDIDATES_MEMBER, json.dumps(candidates, allow_nan=False))
        for name, g in (cameras or {}).items():
            member = io.BytesIO()
            g.write_npz(member)
            zf.writestr(camera_member(name), member.getvalue())
    with atomic_write(path, "wb") as fh:
        fh.write(buf.getvalue())


def read_meta(path: Path) -> dict[str, Any]:
    """The metadata of a checkpoint file as its JSON object (for tools and tests), checked
    as ``read_checkpoint_meta`` does."""
    doc = _read_doc(path)
    CheckpointMeta.from_json(path, doc)
    return doc


def read_checkpoint_meta(path: Path) -> CheckpointMeta:
    """The metadata of a checkpoint file; InputFileError when it has none or is corrupt
    (the fields the daemon resumes from must have the types it wrote: a damaged or foreign
    file is set aside, never half used)."""
    return CheckpointMeta.from_json(path, _read_doc(path))


def _read_doc(path: Path) -> Any:
    def error(why: str) -> InputFileError:
        return InputFileError(f"{path}: not a pdcov checkpoint ({why})")

    text = read_zip_member(path, META_MEMBER, error)
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError) as exc:  # RecursionError: JSON nested too deep
        raise error(f"{META_MEMBER}: {exc}") from None
    return doc


def resume(state_dir: Path, mission_hash: str, new_grid: CoverageGrid,
           new_cameras: Mapping[str, CoverageGrid] | None = None) -> Resumed:
    """The checkpoint in ``state_dir`` if it belongs to this mission and vehicle (same
    hash); otherwise (another mission or vehicle, or unreadable) it is renamed aside with a
    time stamp and the daemon starts fresh. ``new_cameras``: with a cameras list, each
    camera's new grid (by name), whose grids the checkpoint must hold too."""
    path = state_dir / CHECKPOINT_NAME
    # A kill during a write leaves atomic_write's temporary file: never read, removed here
    # (else every crash would leave a grid-sized file behind).
    for stale in state_dir.glob(f".{CHECKPOINT_NAME}.*.tmp"):
        stale.unlink(missing_ok=True)
    if not path.exists():
        return Resumed(None, None, f"no checkpoint in {state_dir}: starting a new grid")
    try:
        meta = read_checkpoint_meta(path)
        if meta.mission_hash != mission_hash:
            vehicle = meta.vehicle_id
            why = (f"it was written for vehicle "
                   f"{'(not recorded)' if vehicle is None else repr(vehicle)} with mission "
                   f"hash {meta.mission_hash}, this daemon's is {mission_hash} (the "
                   "vehicle id, domain, camera, detector or grid settings differ)")
        else:
            grid = _load_like(path, new_grid)
            cameras = {name: _load_camera(path, name, g)
                       for name, g in (new_cameras or {}).items()}
            if any(g.geometry != new_grid.geometry or not (g.mask == new_grid.mask).all()
                   for g in (grid, *cameras.values())):
                why = "its grid geometry differs from this mission's"
            else:
                return Resumed(grid, meta, f"resumed from {path}: {grid.frames} frames, "
                                           f"last frame at t = {meta.last_frame_t_s} s",
                               cameras=cameras or None, **_candidates(path))
    except PdcovError as exc:  # InputFileError, or a DomainError from its geometry
        why = f"it cannot be read ({exc})"
    aside = path.with_name(f"checkpoint-{time.strftime('%Y%m%dT%H%M%S')}.set-aside.npz")
    path.replace(aside)
    return Resumed(None, None, f"checkpoint {path} set aside as {aside.name}: {why}; "
                             "starting a new grid", aside)


def _candidates(path: Path) -> dict[str, Any]:
    """Resumed's ``candidates`` (absent: no such member) or ``candidates_error``."""
    try:
        with zipfile.ZipFile(path) as zf:
            if CANDIDATES_MEMBER not in zf.namelist():
                return {}
            text = zf.read(CANDIDATES_MEMBER)
        return {"candidates": json.loads(text)}
    except DAMAGED as exc:  # RecursionError among them: JSON nested too deep
        return {"candidates_error": f"{type(exc).__name__}: {exc}"}


def _load_like(path: Path, new: CoverageGrid, data: bytes | None = None) -> CoverageGrid:
    """The snapshot at ``path`` (or its member's bytes ``data``) as a grid of ``new``'s
    camera, detector and options."""
    return CoverageGrid.load_npz(path, new.camera, new.detector,
                                 max_range_m=new.max_range_m,
                                 min_revisit_s=new.min_revisit_s, terrain=new.terrain,
                                 exposure_s=new.exposure_s, looks=new.looks, data=data)


def _load_camera(path: Path, name: str, new: CoverageGrid) -> CoverageGrid:
    """Camera ``name``'s own grid in the checkpoint at ``path``."""
    data = read_zip_member(path, camera_member(name), lambda why: InputFileError(
        f"{path}: no grid of camera {name} ({why})"))
    return _load_like(path, new, data)
