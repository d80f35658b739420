"""Tracked sequences in the MOTChallenge layout: each frame's ground truth with the identity
of every box, and the detector's boxes, for the per-person statistics (``detection/looks_fit.py``).

Layout: a folder of sequences (or one sequence folder), each with ``gt/gt.txt`` and the
detections in ``det/det.txt``, or in ``<sequence>.txt`` of a separate detections folder (the
layout of tracker and detector results), lines ``frame,id,left,top,width,height,conf,...``
(image pixels, frames from 1). A VisDrone-MOT split is read in its own layout too:
``annotations/<sequence>.txt`` beside the images in ``sequences/<sequence>/``. Image sizes
from ``seqinfo.ini`` (``imWidth``, ``imHeight``; ``seqLength`` bounds the frames), else a
sizes file of lines ``sequence width height``, else the first image in ``img1/`` (or the
VisDrone sequence's folder).

* ``mot`` (MOT15/16/17/20): ground truth ``frame,id,l,t,w,h,consider,class,visibility``
  (9 fields; MOT15's 10 fields ``...,conf,x,y,z`` are all pedestrians). ``consider`` 0, and
  the classes MOTChallenge's evaluation treats as distractors (person on vehicle, static
  person, distractor, reflection), are ignored ground truth: a detection on one is neither
  true nor false. Detections ``frame,id,l,t,w,h,conf[,x,y,z]`` are pedestrians.
* ``visdrone-mot``: ground truth ``frame,id,l,t,w,h,score,category,truncation,occlusion``
  with VisDrone's categories (0: ignored region; score 0: ignored); detections the same
  (``frame,id,l,t,w,h,score,category[,-1,-1]``), score the confidence.

Errors name the file and line: malformed lines, negative widths or heights, a frame outside
the sequence, an id whose lines go back in time or repeat a frame. A track may be
interrupted (a person leaving the view or fully occluded and coming back); its frames away
are not looks, and the interruptions are counted.
"""

from __future__ import annotations

import configparser
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pdcov.detection.formats.fields import (
    IMAGE_SUFFIXES,
    class_id_of,
    detection_score,
    file_lines,
    line_numbers,
    read_sizes,
)
from pdcov.detection.formats.visdrone import VISDRONE_CLASSES
from pdcov.detection.truth_set import NO_BOXES, Boxes, ImageTruth
from pdcov.errors import ConfigError, InputFileError

TRACK_FORMATS = ("mot", "visdrone-mot")
# MOT16 paper, table 5: class ids 1..12.
MOT_CLASSES = ("pedestrian", "person_on_vehicle", "car", "bicycle", "motorbike",
               "non_motorized_vehicle", "static_person", "distractor", "occluder",
               "occluder_on_the_ground", "occluder_full", "reflection")
MOT_DEFAULT_CLASSES = ("pedestrian",)  # det.txt has no class: every detection is one
# MOTChallenge's evaluation (TrackEval) drops detections on these as neither true nor false.
_MOT_DISTRACTORS = frozenset({2, 7, 8, 12})


@dataclass(frozen=True, slots=True)
class TrackedFrame:
    """One frame: its ground truth (image id ``sequence:frame``), the index into
    ``TrackedSet.people`` of each ground-truth box, and the detections."""

    truth: ImageTruth
    person: np.ndarray
    detections: Boxes


@dataclass(frozen=True, slots=True)
class TrackedSet:
    """Tracked sequences: frames in sequence and time order; people as ``sequence:id``;
    ``n_track_gaps``: times a track resumed after frames without it."""

    frames: tuple[TrackedFrame, ...]
    people: tuple[str, ...]
    sequences: tuple[str, ...]
    classes: tuple[str, ...]
    source: str
    format: str
    n_track_gaps: int


def tracked_format(path: Path) -> str | None:
    """``mot`` for a MOTChallenge sequence folder or a folder of them, ``visdrone-mot`` for a
    VisDrone-MOT split (``annotations/`` beside ``sequences/``), else None."""
    if not path.is_dir():
        return None
    if (path / "annotations").is_dir() and (path / "sequences").is_dir():
        return "visdrone-mot"
    if (path / "gt" / "gt.txt").is_file() or any(
            (p / "gt" / "gt.txt").is_file() for p in path.iterdir() if p.is_dir()):
        return "mot"
    return None


@dataclass(frozen=True, slots=True)
class _Sequence:
    """Where one sequence's files are: its name, ground truth, and the folder of its
    seqinfo.ini and images."""

    name: str
    gt_file: Path
    folder: Path


def _sequences(gt_root: Path) -> list[_Sequence]:
    if (gt_root / "gt" / "gt.txt").is_file():
        return [_Sequence(gt_root.name, gt_root / "gt" / "gt.txt", gt_root)]
    if not gt_root.is_dir():
        raise InputFileError(f"{gt_root}: expected a MOTChallenge folder of sequences (each "
                             f"with gt/gt.txt) or a VisDrone-MOT split (annotations/)")
    if (gt_root / "annotations").is_dir():  # VisDrone-MOT: annotations/<seq>.txt
        files = sorted((gt_root / "annotations").glob("*.txt"))
        if not files:
            raise InputFileError(f"{gt_root / 'annotations'}: no <sequence>.txt annotations")
        return [_Sequence(f.stem, f, gt_root / "sequences" / f.stem) for f in files]
    seqs = []
    for folder in sorted(p for p in gt_root.iterdir() if p.is_dir()):
        if not (folder / "gt" / "gt.txt").is_file():
            raise InputFileError(f"{folder}: sequence without ground truth (no gt/gt.txt)")
        seqs.append(_Sequence(folder.name, folder / "gt" / "gt.txt", folder))
    if not seqs:
        raise InputFileError(f"{gt_root}: expected a MOTChallenge folder of sequences, each "
                             f"with gt/gt.txt")
    return seqs


def read_tracked(gt_root: str | Path, det_root: str | Path, fmt: str = "mot",
                 sizes_path: str | Path | None = None) -> TrackedSet:
    """Read every sequence under ``gt_root`` with its detections from ``det_root`` (the same
    folder, or a folder of ``<sequence>.txt``)."""
    gt_root, det_root = Path(gt_root), Path(det_root)
    if fmt not in TRACK_FORMATS:
        raise ConfigError(f"--format: expected one of {TRACK_FORMATS}, got {fmt!r}")
    for p in (gt_root, det_root):
        if not p.exists():
            raise InputFileError(f"{p}: no such file or directory")
    seqs = _sequences(gt_root)
    sizes = read_sizes(Path(sizes_path)) if sizes_path is not None else {}
    frames: list[TrackedFrame] = []
    people: list[str] = []
    gaps = 0
    for seq in seqs:
        det_file = _detections_file(seq, det_root)
        width, height, length = _sequence_info(seq, sizes)
        truth, regions, n_gaps = _read_truth(seq.gt_file, fmt, length, people, seq.name)
        dets = _read_detections(det_file, fmt, length)
        gaps += n_gaps
        last = max([*truth, *regions, *dets, length or 0])
        for f in range(1, last + 1):
            rows = truth.get(f, [])
            boxes = Boxes.from_rows([r[1] for r in rows], [r[2] for r in rows],
                                    ignore=[r[3] for r in rows])
            image = ImageTruth(f"{seq.name}:{f}", width, height, boxes,
                               np.asarray(regions.get(f, []), float).reshape(-1, 4))
            frames.append(TrackedFrame(image, np.array([r[0] for r in rows], int),
                                       dets.get(f, NO_BOXES)))
    classes = MOT_CLASSES if fmt == "mot" else VISDRONE_CLASSES[1:]
    return TrackedSet(tuple(frames), tuple(people), tuple(s.name for s in seqs), classes,
                      str(gt_root), fmt, gaps)


def _detections_file(seq: _Sequence, det_root: Path) -> Path:
    """``<det_root>/<sequence>/det/det.txt`` or ``<det_root>/<sequence>.txt``; a sequence
    folder given as both roots holds its own ``det/det.txt``."""
    candidates = [det_root / seq.name / "det" / "det.txt", det_root / f"{seq.name}.txt"]
    if det_root.resolve() == seq.folder.resolve():
        candidates.insert(0, seq.folder / "det" / "det.txt")
    for c in candidates:
        if c.is_file():
            return c
    raise InputFileError(f"{seq.folder}: no detections for sequence {seq.name!r} (looked for "
                         f"{', '.join(map(str, candidates))})")


def _sequence_info(seq: _Sequence, sizes: dict[str, tuple[int, int]]
                   ) -> tuple[int | None, int | None, int | None]:
    """(width, height, number of frames) of a sequence, None where unknown: seqinfo.ini,
    the sizes file, or the first image in ``img1/`` (MOTChallenge) or the sequence's folder
    (VisDrone-MOT's ``sequences/<seq>/``)."""
    width = height = length = None
    ini = seq.folder / "seqinfo.ini"
    if ini.is_file():
        cp = configparser.ConfigParser()
        try:
            cp.read(ini)
            s = cp["Sequence"]
            width, height = s.getint("imWidth"), s.getint("imHeight")
            length = s.getint("seqLength")
        except (configparser.Error, KeyError, ValueError) as exc:
            raise InputFileError(f"{ini}: expected a [Sequence] section with integer imWidth, "
                                 f"imHeight and seqLength ({exc})") from None
    if seq.name in sizes:
        width, height = sizes[seq.name]
    images = seq.folder / "img1" if (seq.folder / "img1").is_dir() else seq.folder
    if width is None and images.is_dir():
        first = next((p for p in sorted(images.iterdir())
                      if p.suffix.lower() in IMAGE_SUFFIXES), None)
        if first is not None:
            try:
                from PIL import Image
                with Image.open(first) as im:
                    width, height = im.size
            except (ImportError, OSError) as exc:
                raise InputFileError(f"{first}: cannot read the image size ({exc}); give "
                                     f"seqinfo.ini or --sizes") from None
    for key, v in (("imWidth", width), ("imHeight", height), ("seqLength", length)):
        if v is not None and v <= 0:
            raise InputFileError(f"{seq.folder}: {key} must be positive, got {v}")
    return width, height, length


_Row = tuple[int, tuple[float, float, float, float], str, bool]


def _frame_and_box(where: str, v: list[float], length: int | None
                   ) -> tuple[int, tuple[float, float, float, float]]:
    frame = v[0]
    if frame != int(frame) or frame < 1:
        raise InputFileError(f"{where}: frame must be an integer >= 1, got {frame:g}")
    if length is not None and frame > length:
        raise InputFileError(f"{where}: frame {frame:g} beyond the sequence's {length} frames "
                             f"(seqinfo.ini seqLength)")
    if v[4] < 0 or v[5] < 0:
        raise InputFileError(f"{where}: negative box width or height ({v[4]:g} x {v[5]:g})")
    return int(frame), (v[2], v[3], v[4], v[5])


def _read_truth(path: Path, fmt: str, length: int | None, people: list[str], seq: str
                ) -> tuple[dict[int, list[_Row]], dict[int, list[tuple[float, ...]]], int]:
    """Rows per frame (person index, xywh, class, ignore), ignored regions per frame, and
    the number of track interruptions. New people are appended to ``people``."""
    layout = ("'frame,id,left,top,width,height,consider,class,visibility'" if fmt == "mot" else
              "'frame,id,left,top,width,height,score,category,truncation,occlusion'")
    rows: dict[int, list[_Row]] = defaultdict(list)
    regions: dict[int, list[tuple[float, ...]]] = defaultdict(list)
    index: dict[int, int] = {}
    last: dict[int, tuple[int, str]] = {}
    gaps = 0
    for where, fields in file_lines(path):
        v = line_numbers(where, fields, (9, 10) if fmt == "mot" else (10,), layout)
        frame, box = _frame_and_box(where, v, length)
        if fmt == "mot" and len(v) == 9:
            cls = class_id_of(where, v[7])
            if not 1 <= cls <= len(MOT_CLASSES):
                raise InputFileError(f"{where}: MOT class must be 1..{len(MOT_CLASSES)}, "
                                     f"got {cls}")
            ignore = v[6] == 0 or cls in _MOT_DISTRACTORS
            label = "pedestrian" if cls in _MOT_DISTRACTORS else MOT_CLASSES[cls - 1]
        elif fmt == "mot":  # MOT15: every box a pedestrian
            ignore, label = False, "pedestrian"
        else:
            cls = class_id_of(where, v[7])
            if cls >= len(VISDRONE_CLASSES):
                raise InputFileError(f"{where}: VisDrone category must be 0..11, got {cls}")
            if cls == 0:
                regions[frame].append(box)
                continue
            ignore, label = v[6] == 0, VISDRONE_CLASSES[cls]
        if v[1] != int(v[1]):
            raise InputFileError(f"{where}: id must be an integer, got {v[1]:g}")
        track = int(v[1])
        if track in last:
            prev, prev_where = last[track]
            if frame <= prev:
                raise InputFileError(
                    f"{where}: id {track} in frame {frame} after frame {prev} ({prev_where}); "
                    + ("an id appears once per frame" if frame == prev else
                       "a track's lines must be in frame order"))
            gaps += frame > prev + 1
        else:
            index[track] = len(people)
            people.append(f"{seq}:{track}")
        last[track] = (frame, where)
        rows[frame].append((index[track], box, label, bool(ignore)))
    return rows, regions, gaps


def _read_detections(path: Path, fmt: str, length: int | None) -> dict[int, Boxes]:
    layout = ("'frame,id,left,top,width,height,conf[,x,y,z]'" if fmt == "mot" else
              "'frame,id,left,top,width,height,score,category[,truncation,occlusion]'")
    rows: dict[int, list[tuple[tuple[float, ...], str, float]]] = defaultdict(list)
    for where, fields in file_lines(path):
        v = line_numbers(where, fields, (7, 10) if fmt == "mot" else (8, 10), layout)
        frame, box = _frame_and_box(where, v, length)
        if fmt == "mot":
            label = "pedestrian"
        else:
            cls = class_id_of(where, v[7])
            if not 1 <= cls < len(VISDRONE_CLASSES):
                raise InputFileError(f"{where}: VisDrone detection category must be 1..11, "
                                     f"got {cls}")
            label = VISDRONE_CLASSES[cls]
        rows[frame].append((box, label, detection_score(where, v[6])))
    return {f: Boxes.from_rows([r[0] for r in rs], [r[1] for r in rs], [r[2] for r in rs])
            for f, rs in rows.items()}
