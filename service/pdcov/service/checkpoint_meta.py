"""What a checkpoint holds besides the grid, as a value, and the checkpoint's state as the
status reports it: no I/O (checkpoint.py reads and writes the files).

``CheckpointMeta`` is built by the service core when a checkpoint is due and parsed from a
file's ``pdcov_checkpoint.json`` (``from_json``): a damaged or foreign file raises
``InputFileError`` there, once, and the daemon's decisions never see a half-valid dict.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pdcov.errors import InputFileError

META_VERSION = 1


def _finite(v: Any) -> bool:
    # abs(v) <= max float: false for NaN and infinities, and for a JSON integer no float
    # holds (math.isfinite raises OverflowError on it).
    return (isinstance(v, (int, float)) and not isinstance(v, bool)
            and abs(v) <= sys.float_info.max)


def _count(v: Any, least: int) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= least


_CHECKS = {"mission_hash": lambda v: isinstance(v, str),
           "vehicle_id": lambda v: isinstance(v, str),
           "t0_s": lambda v: v is None or _finite(v),
           "last_frame_t_s": lambda v: v is None or _finite(v),
           "clock": lambda v: v is None or (isinstance(v, list) and len(v) == 2
                                            and all(_finite(x) for x in v)),
           "tiles_seq": lambda v: _count(v, -1),
           "frames_used": lambda v: _count(v, 0),
           "written_unix_s": lambda v: v is None or _finite(v),
           "cameras": lambda v: isinstance(v, dict) and all(
               isinstance(k, str) and isinstance(x, list) and len(x) == 3
               and all(t is None or _finite(t) for t in x[:2]) and _count(x[2], 0)
               for k, x in v.items())}


@dataclass(frozen=True, slots=True)
class CameraResume:
    """One camera of a cameras list in a checkpoint: its frame lattice's anchor t0_s and
    last decided frame (autopilot clock, s; None: none) and the frames its grid took."""

    t0_s: float | None
    last_frame_t_s: float | None
    frames_used: int


@dataclass(frozen=True, slots=True)
class CheckpointMeta:
    """The grid's context: mission_hash (settings.mission_hash) and vehicle_id; the frame
    lattice's anchor t0_s and the last decided frame (autopilot clock, s; None: none);
    clock_offset_s / clock_boot_s, the autopilot clock to continue (None: not known yet);
    mission_hash None only in a file written by hand (then it belongs to no mission);
    tiles_seq, the last tiles message sent (-1: none); frames_used; written_unix_s (wall
    clock, for people only); cameras: with a cameras list, each camera's lattice and frames
    (``CameraResume``; the fields above are the first camera's)."""

    mission_hash: str | None
    vehicle_id: str | None = None
    t0_s: float | None = None
    last_frame_t_s: float | None = None
    clock_offset_s: float | None = None
    clock_boot_s: float | None = None
    tiles_seq: int = -1
    frames_used: int = 0
    written_unix_s: float | None = None
    cameras: dict[str, CameraResume] | None = None  # a cameras list's, by name

    def to_json(self) -> dict[str, Any]:
        """The JSON object written (format version 1, docs/service.md)."""
        clock = (None if self.clock_offset_s is None or self.clock_boot_s is None
                 else [self.clock_offset_s, self.clock_boot_s])
        return {"version": META_VERSION, "mission_hash": self.mission_hash,
                "vehicle_id": self.vehicle_id, "t0_s": self.t0_s,
                "last_frame_t_s": self.last_frame_t_s, "clock": clock,
                "tiles_seq": self.tiles_seq, "frames_used": self.frames_used,
                "written_unix_s": self.written_unix_s,
                **({} if self.cameras is None else {"cameras": {
                    name: [c.t0_s, c.last_frame_t_s, c.frames_used]
                    for name, c in self.cameras.items()}})}

    @classmethod
    def from_json(cls, path: Path, doc: Any) -> CheckpointMeta:
        """The metadata of ``doc`` (the parsed JSON of ``path``); InputFileError naming the
        file and field when it is not what pdcov writes."""
        if not isinstance(doc, dict) or doc.get("version") != META_VERSION:
            raise InputFileError(f"{path}: checkpoint metadata version "
                                 f"{doc.get('version') if isinstance(doc, dict) else '?'}, "
                                 f"expected {META_VERSION}")
        for name, check in _CHECKS.items():
            if name in doc and not check(doc[name]):
                raise InputFileError(f"{path}: checkpoint metadata {name} = {doc[name]!r} "
                                     "is not what pdcov writes")
        clock = doc.get("clock")

        def num(key: str) -> float | None:
            v = doc.get(key)
            return None if v is None else float(v)

        return cls(mission_hash=doc.get("mission_hash"), vehicle_id=doc.get("vehicle_id"),
                   t0_s=num("t0_s"), last_frame_t_s=num("last_frame_t_s"),
                   clock_offset_s=None if clock is None else float(clock[0]),
                   clock_boot_s=None if clock is None else float(clock[1]),
                   tiles_seq=int(doc.get("tiles_seq", -1)),
                   frames_used=int(doc.get("frames_used", 0)),
                   written_unix_s=num("written_unix_s"),
                   cameras=None if "cameras" not in doc else {
                       name: CameraResume(None if x[0] is None else float(x[0]),
                                          None if x[1] is None else float(x[1]), int(x[2]))
                       for name, x in doc["cameras"].items()})


@dataclass(frozen=True, slots=True)
class CheckpointContents:
    """What one checkpoint copied: the grid's frames and the last journal line decided then
    (a line after it is not in the checkpoint, so the journal keeps it)."""

    frames: int
    journal_seq: int


@dataclass(slots=True)
class CheckpointState:
    """The checkpoint as the status reports it (docs/protocol.md ``checkpoint``), and the
    error state: ``error`` is why the last write failed (None once one succeeds);
    ``candidates_restored``: the candidates held after the start restored them,
    ``candidates_from_journal`` of them those the journal added or updated."""

    path: str
    resumed: bool = False
    set_aside: str | None = None
    last_t_s: float | None = None
    error: str | None = None
    recording_error: str | None = None
    written_unix_s: float | None = None
    frames: int | None = None
    candidates_restored: int = 0
    candidates_from_journal: int = 0

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {"path": self.path, "last_t_s": self.last_t_s,
                               "resumed": self.resumed, "set_aside": self.set_aside,
                               "error": self.error, "recording_error": self.recording_error,
                               "candidates_restored": self.candidates_restored,
                               "candidates_from_journal": self.candidates_from_journal}
        if self.frames is not None:  # once a checkpoint was written
            out.update(written_unix_s=self.written_unix_s, frames=self.frames)
        return out


def finite_or_none(v: float) -> float | None:
    return v if math.isfinite(v) else None
