"""The inputs of ``pdcov detector fit`` and ``validate``: a labelled image set (COCO, YOLO,
VisDrone, odm) or tracked sequences (MOT), read from the command's options and matched
(detection/matching.py), with each image's blur when a blur CSV is given."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

from tqdm import tqdm

from pdcov.detection.annotations import read_detections, read_truth
from pdcov.detection.blur_sidecar import SpeedToBlur, read_blur_csv
from pdcov.detection.matching import Matches, MatchSettings, match_images
from pdcov.detection.tracks import (
    MOT_DEFAULT_CLASSES,
    TRACK_FORMATS,
    TrackedSet,
    read_tracked,
    tracked_format,
)
from pdcov.detection.truth_set import NO_BOXES, Boxes, ImageTruth
from pdcov.errors import ConfigError, InputFileError


def inputs_format(args: argparse.Namespace) -> str | None:
    """The tracked-sequence format of the inputs, or None for a labelled image set."""
    if args.format in TRACK_FORMATS:
        return str(args.format)
    return tracked_format(args.ground_truth) if args.format is None else None


def read_tracked_inputs(args: argparse.Namespace, fmt: str,
                        settings: MatchSettings) -> tuple[TrackedSet, MatchSettings]:
    """The sequences, and the settings with the format's default class set (MOT: pedestrian,
    since det.txt has no class)."""
    tracked = read_tracked(args.ground_truth, args.detections, fmt, args.sizes)
    if settings.classes is None and fmt == "mot":
        settings = replace(settings, classes=MOT_DEFAULT_CLASSES)
    if settings.classes is not None:
        unknown = [c for c in settings.classes if c not in tracked.classes]
        if unknown:
            raise ConfigError(f"--classes: {', '.join(map(repr, unknown))} not among the "
                              f"{fmt} classes: {', '.join(tracked.classes)}")
    if settings.input_size_px is not None:
        for f in tracked.frames:
            if f.truth.width_px is None:
                seq = f.truth.image_id.rsplit(":", 1)[0]
                raise InputFileError(
                    f"{args.ground_truth}: image size of sequence {seq!r} unknown; give its "
                    f"seqinfo.ini, img1/ images or --sizes FILE ('sequence width height'), "
                    f"or --input-size none to keep image pixels")
    if not tracked.frames:
        raise InputFileError(f"{tracked.source}: no frames")
    return tracked, settings


def tracked_frames(args: argparse.Namespace, tracked: TrackedSet) -> Iterator[Any]:
    """The sequences' frames, with a progress bar on stderr unless --quiet."""
    return iter(tqdm(tracked.frames, desc="matching", unit="frame", disable=args.quiet,
                     file=sys.stderr))


def match_inputs(args: argparse.Namespace, settings: MatchSettings,
                 blur_csv: Path | None = None, speed: SpeedToBlur | None = None) -> Matches:
    """The matches of the set; with each image's blur when ``blur_csv`` is given."""
    fmt = inputs_format(args)
    if fmt is not None:  # every frame an image
        tracked, settings = read_tracked_inputs(args, fmt, settings)
        return match_images(((f.truth, f.detections) for f in tracked_frames(args, tracked)),
                            settings)
    truth = read_truth(args.ground_truth, args.format, args.images, args.sizes, args.names,
                       args.box_format)
    blur = read_blur_csv(blur_csv, truth, speed) if blur_csv is not None else None
    detections = read_detections(args.detections, truth, args.detections_format or args.format,
                                 args.box_format)
    if settings.classes is not None:
        truth.check_classes(settings.classes)
    if settings.input_size_px is not None:
        truth.check_sizes()
    if not truth.images:
        raise InputFileError(f"{truth.source}: no images")

    def pairs() -> Iterator[tuple[ImageTruth, Boxes]]:
        for image_id, image in tqdm(truth.images.items(), desc="matching", unit="image",
                                    disable=args.quiet, file=sys.stderr):
            yield image, detections.get(image_id, NO_BOXES)

    return match_images(pairs(), settings, blur)
