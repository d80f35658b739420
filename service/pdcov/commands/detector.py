"""``pdcov detector fit | validate | plot``: build, check and draw a detector model.

The workflow and the formats are described in docs/detector-statistics.md; the model file in
docs/detector-model.md.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from pdcov.atomic import write_text_atomic
from pdcov.commands.args import output_file
from pdcov.commands.detector_inputs import (
    inputs_format,
    match_inputs,
    read_tracked_inputs,
    tracked_frames,
)
from pdcov.commands.detector_tables import (
    format_blur_table,
    format_confidence_table,
    format_looks_table,
    format_model_table,
    format_validation_table,
)
from pdcov.core.detector import DetectorModel
from pdcov.detection.annotations import BOX_FORMATS, FORMATS
from pdcov.detection.bins import BIN_RULES, INTERVAL_METHODS, auto_bin_edges
from pdcov.detection.blur_sidecar import SpeedToBlur
from pdcov.detection.logistic import fit_logistic
from pdcov.detection.looks_fit import collect_looks, fit_looks
from pdcov.detection.matching import DEFAULT_MAX_DETECTIONS, MatchSettings
from pdcov.detection.statistics import (
    DEFAULT_CONFIDENCE_BINS,
    blur_bin_edges,
    fit_binned,
    fit_binned_blur,
    fit_confidence,
)
from pdcov.detection.tracks import TRACK_FORMATS
from pdcov.detection.validation import VALIDATION_TESTS, ValidationReport, validate
from pdcov.errors import ConfigError, InputFileError

DEFAULT_BINS = "quantile:20"
DEFAULT_BLUR_BINS = "quantile:4"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "detector", help="fit, validate and plot a detector model (P_D, P_FA by object size)",
        description="Detector statistics of the paper's section III-B.")
    sub = p.add_subparsers(dest="detector_command", metavar="ACTION", required=True)

    fit = sub.add_parser("fit", help="fit P_D(size) and P_FA(size) from a labelled test set")
    _data_args(fit)
    fit.add_argument("--out", required=True, type=output_file, help="detector model YAML to write")
    fit.add_argument("--bins", default=DEFAULT_BINS,
                     help="edges '4,8,16,...' (px) or a rule 'quantile:N' (equal counts) or "
                          f"'log:N' (log-spaced) on the ground-truth sizes "
                          f"(default {DEFAULT_BINS})")
    fit.add_argument("--conf", type=float, default=0.5, help="confidence threshold (0.5)")
    fit.add_argument("--iou", type=float, default=0.5, help="IoU threshold (0.5)")
    fit.add_argument("--classes", help="comma-separated class names, each matched within its "
                                       "class (COCO) and then merged into one target class "
                                       "(default: every class)")
    fit.add_argument("--max-detections", default=str(DEFAULT_MAX_DETECTIONS),
                     help="per image and class, evaluate only this many detections of highest "
                          "confidence, as COCO's maxDets ('none': all; default 100)")
    fit.add_argument("--input-size", default="640",
                     help="detector input size in px; box sizes are scaled by it over the "
                          "image's longest side ('none': image pixels; default 640)")
    fit.add_argument("--interval", choices=tuple(INTERVAL_METHODS), default="wilson",
                     help="95 %% interval of the binned proportions (wilson)")
    fit.add_argument("--model", choices=("binned", "logistic"), default="binned",
                     help="binned histogram (the paper) or logistic in log size")
    fit.add_argument("--logistic-degree", type=int, default=1, choices=(1, 2),
                     help="polynomial degree in log size of the logistic model (1)")
    fit.add_argument("--fine-bins", type=int, default=64,
                     help="log-spaced bins the logistic model is written on (64)")
    fit.add_argument("--confidence-bins", type=int, default=DEFAULT_CONFIDENCE_BINS,
                     help="equal confidence bins over [--conf, 1] of the histograms of true "
                          "and false boxes' confidences per size bin, the evidence a box's "
                          f"confidence gives (the model's confidence section; "
                          f"{DEFAULT_CONFIDENCE_BINS})")
    fit.add_argument("--blur-csv", type=Path,
                     help="CSV of each image's motion blur: columns image,blur_px (image px) "
                          "or image,speed_m_s,height_m (with --focal-px and --exposure-s); "
                          "adds P_D and P_FA by blur and size (the model's blur section)")
    fit.add_argument("--blur-bins", default=DEFAULT_BLUR_BINS,
                     help="blur bin edges '0,1,2,4' (detector-input px, first 0) or a rule "
                          f"'quantile:N' / 'log:N' on the objects' blurs ({DEFAULT_BLUR_BINS})")
    fit.add_argument("--focal-px", type=float,
                     help="focal length (image px) of the test set's camera, for speed_m_s")
    fit.add_argument("--exposure-s", type=float,
                     help="exposure time (s) of the test set's camera, for speed_m_s")
    fit.set_defaults(func=run_fit)

    val = sub.add_parser("validate", help="test a model against a second split")
    val.add_argument("model", type=Path, help="detector model YAML")
    _data_args(val)
    val.add_argument("--classes", help="class names (default: those the model was fitted on)")
    val.add_argument("--bins", help="bins to test in, as for fit (default: the model's)")
    val.add_argument("--test", choices=VALIDATION_TESTS, default="binomial",
                     help="per-bin test against the model's predictions: exact binomial or "
                          "chi-square; or Fisher's exact test against the fit's counts "
                          "(binomial)")
    val.add_argument("--alpha", type=float, default=0.05, help="significance level (0.05)")
    val.add_argument("--report", type=output_file, help="write the per-bin report as JSON")
    val.set_defaults(func=run_validate)

    plot = sub.add_parser("plot", help="draw the paper's Fig. 6: P_D and precision by size, "
                                       "and the false boxes per frame per Mpx beside them")
    plot.add_argument("model", type=Path, help="detector model YAML")
    plot.add_argument("--validation", type=Path, help="report JSON of 'detector validate'")
    plot.add_argument("--out", required=True, type=output_file, help="image to write (.png, .pdf)")
    plot.add_argument("--title", help="figure title")
    plot.add_argument("--looks", type=output_file,
                      help="also draw the share of people found within n looks (measured, "
                           "independent, beta-binomial) of a model fitted on tracked "
                           "sequences to this image")
    plot.set_defaults(func=run_plot)


def _data_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--ground-truth", required=True, type=Path,
                   help="COCO instances JSON, a directory of YOLO / VisDrone label files, or "
                        "a MOTChallenge folder of tracked sequences (each with gt/gt.txt)")
    p.add_argument("--detections", required=True, type=Path,
                   help="COCO results JSON, a directory of YOLO / VisDrone txt files, or for "
                        "tracked sequences the sequences' folder (det/det.txt) or a folder "
                        "of <sequence>.txt")
    p.add_argument("--format", choices=FORMATS + TRACK_FORMATS,
                   help="format of both: coco, yolo, visdrone, odm (Object-Detection-Metrics "
                        "'class [confidence] left top width height' per image), or tracked "
                        "sequences: mot (MOTChallenge) or visdrone-mot; default: .json is "
                        "COCO, a folder with gt/gt.txt is mot, else guessed from the text")
    p.add_argument("--detections-format", choices=FORMATS,
                   help="format of the detections if it differs from the ground truth's")
    p.add_argument("--images", type=Path, help="image directory, for image sizes")
    p.add_argument("--sizes", type=Path, help="file of lines 'image width height'")
    p.add_argument("--names", type=Path, help="YOLO class names (data YAML or one a line)")
    p.add_argument("--box-format", choices=BOX_FORMATS, default="xywh",
                   help="boxes of the odm format (Object-Detection-Metrics text files): "
                        "'xywh' left top width height, or 'xyrb' left top right bottom "
                        "(default xywh)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


# -- fit -------------------------------------------------------------------------------------


def _parse_bins(spec: str, option: str = "--bins") -> tuple[str, int] | tuple[float, ...]:
    """'quantile:20' -> ('quantile', 20); '4,8,16' -> (4.0, 8.0, 16.0)."""
    rule, _, n = spec.partition(":")
    if rule in BIN_RULES:
        try:
            return rule, int(n)
        except ValueError:
            raise ConfigError(f"{option}: expected {rule}:N with an integer N, got {spec!r}") \
                from None
    try:
        return tuple(float(v) for v in spec.split(","))
    except ValueError:
        raise ConfigError(f"{option}: expected comma-separated edges in px or "
                          f"{' / '.join(r + ':N' for r in BIN_RULES)}, got {spec!r}") from None


def _edges(spec: str, values_px: np.ndarray, option: str = "--bins",
           auto: Callable[[np.ndarray, str, int], tuple[float, ...]] = auto_bin_edges
           ) -> tuple[float, ...]:
    """Bin edges (px) as given, or by ``auto`` from a rule on ``values_px``."""
    bins = _parse_bins(spec, option)
    if isinstance(bins[0], str):
        rule, n = bins
        return auto(values_px, str(rule), int(n))
    return tuple(float(v) for v in bins)


def _int_or_none(text: str, option: str, what: str) -> int | None:
    """An integer option that also takes 'none'."""
    if text.lower() == "none":
        return None
    try:
        return int(text)
    except ValueError:
        raise ConfigError(f"{option}: expected {what} or 'none', got {text!r}") from None


def _classes(text: str | None) -> tuple[str, ...] | None:
    return tuple(c.strip() for c in text.split(",") if c.strip()) if text else None


def _dump(model: DetectorModel) -> str:
    return yaml.safe_dump(model.to_dict(), sort_keys=False, default_flow_style=None, width=100)


def run_fit(args: argparse.Namespace) -> int:
    settings = MatchSettings(
        args.conf, args.iou, _int_or_none(args.input_size, "--input-size", "a number of pixels"),
        _classes(args.classes),
        _int_or_none(args.max_detections, "--max-detections", "a number of detections"))
    speed = None
    if args.focal_px is not None or args.exposure_s is not None:
        if args.focal_px is None or args.exposure_s is None or args.blur_csv is None:
            raise ConfigError("--focal-px and --exposure-s go together, with a --blur-csv "
                              "giving speed_m_s")
        speed = SpeedToBlur(args.focal_px, args.exposure_s)
    if args.blur_csv is not None and args.model == "logistic":
        raise ConfigError("--blur-csv: the blur tables are binned; use --model binned")
    fmt = inputs_format(args)
    looks_fit = None
    if fmt is not None:
        if args.model != "binned":
            raise ConfigError("--model logistic: tracked sequences are fitted with the binned "
                              "model (the correlation of the looks is estimated per bin)")
        if args.blur_csv is not None:
            raise ConfigError("--blur-csv: blur tables are fitted on labelled image sets, "
                              "not on tracked sequences")
        tracked, settings = read_tracked_inputs(args, fmt, settings)
        matches, looks = collect_looks(tracked_frames(args, tracked), len(tracked.people), settings)
    else:
        matches = match_inputs(args, settings, args.blur_csv, speed)
    edges = _edges(args.bins, matches.truth_size_px)
    if args.model == "logistic":
        model = fit_logistic(matches, edges, args.fine_bins, args.logistic_degree)
    elif args.blur_csv is not None:
        model = fit_binned_blur(matches, edges, _edges(args.blur_bins, matches.truth_blur_px,
                                                       "--blur-bins", blur_bin_edges),
                                args.interval)
        assert model.blur is not None
        model = replace(model, blur=replace(model.blur, extra={
            **model.blur.extra, "csv": str(args.blur_csv), "bins": args.blur_bins,
            **({"speed_to_blur": {"focal_px": speed.focal_px, "exposure_s": speed.exposure_s}}
               if speed is not None else {})}))
    else:
        model = fit_binned(matches, edges, args.interval)
    fit = {**model.extra["fit"], "ground_truth": str(args.ground_truth),
           "detections": str(args.detections), "bins": args.bins}
    model = replace(model, extra={**model.extra, "fit": fit},
                    confidence=fit_confidence(matches, model.bin_edges_px,
                                              args.confidence_bins))
    if fmt is not None:
        looks_fit = fit_looks(looks, edges)
        model = replace(model, looks=looks_fit.to_model({
            "format": fmt, "n_sequences": len(tracked.sequences),
            "n_frames": len(tracked.frames), "n_people": len(tracked.people),
            "n_track_gaps": tracked.n_track_gaps,
            "looks_outside_bins": looks_fit.looks_outside_bins}))
    write_text_atomic(args.out, _dump(model))
    print(format_model_table(model))
    if looks_fit is not None:
        print(format_looks_table(model, looks_fit))
    if model.blur is not None:
        print(format_blur_table(model))
    if model.confidence is not None:
        print(format_confidence_table(model))
    print(f"{matches.n_images} {'frames' if fmt else 'images'}; "
          f"{len(matches.truth_size_px)} objects, "
          f"{len(matches.detection_size_px)} detections counted; outside the bins: "
          f"{fit['truth_outside_bins']} objects, {fit['detections_outside_bins']} detections")
    dropped = {k: v for k, v in fit["status_counts"].items()
               if not k.endswith(("_missed", "_detected", "_true", "_false"))}
    if dropped:
        print("not counted: " + ", ".join(f"{k} {v}" for k, v in dropped.items()))
    print(f"wrote {args.out}")
    return 0


# -- validate --------------------------------------------------------------------------------


def run_validate(args: argparse.Namespace) -> int:
    model = DetectorModel.from_yaml(args.model)
    fit = model.extra.get("fit")
    fitted = fit.get("classes") if isinstance(fit, dict) else None
    classes = _classes(args.classes) or (tuple(fitted) if fitted else None)
    # The fit's detection cap; fits written before it was recorded had none.
    cap = fit.get("max_detections") if isinstance(fit, dict) else DEFAULT_MAX_DETECTIONS
    settings = MatchSettings(
        model.confidence_threshold if model.confidence_threshold is not None else 0.5,
        model.iou_threshold if model.iou_threshold is not None else 0.5,
        model.input_size_px, classes, cap)
    matches = match_inputs(args, settings)
    edges = _edges(args.bins, matches.truth_size_px) if args.bins else None
    report = validate(model, matches, edges, args.test, args.alpha)
    report = replace(report, model={"path": str(args.model),
                                    "ground_truth": str(args.ground_truth),
                                    "detections": str(args.detections)})
    print(format_validation_table(report))
    if args.report:
        write_text_atomic(args.report, json.dumps(report.to_dict(), indent=1) + "\n")
        print(f"wrote {args.report}")
    return 0


# -- plot ------------------------------------------------------------------------------------


def run_plot(args: argparse.Namespace) -> int:
    from pdcov.detection.figures import plot_detector_model, plot_looks

    model = DetectorModel.from_yaml(args.model)
    report = None
    if args.validation:
        try:
            doc = json.loads(args.validation.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise InputFileError(f"{args.validation}: cannot read validation report "
                                 f"({exc})") from None
        report = ValidationReport.from_dict(doc, str(args.validation))
    plot_detector_model(model, args.out, report, args.title)
    print(f"wrote {args.out}")
    if args.looks:
        plot_looks(model, args.looks)
        print(f"wrote {args.looks}")
    return 0
