"""``pdcov detector fit | validate | plot``: build, check and draw a detector model.

The workflow and the formats are described in docs/detector-statistics.md; the model file in
docs/detector-model.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from tqdm import tqdm

from pdcov.atomic import write_text_atomic
from pdcov.commands.args import output_file
from pdcov.core.detector import DetectorModel
from pdcov.detection.annotations import BOX_FORMATS, FORMATS, read_detections, read_truth
from pdcov.detection.bins import BIN_RULES, INTERVAL_METHODS, auto_bin_edges
from pdcov.detection.blur_sidecar import SpeedToBlur, read_blur_csv
from pdcov.detection.logistic import fit_logistic
from pdcov.detection.looks_fit import LooksFit, collect_looks, fit_looks, found_within
from pdcov.detection.matching import DEFAULT_MAX_DETECTIONS, Matches, MatchSettings, match_images
from pdcov.detection.statistics import (
    DEFAULT_CONFIDENCE_BINS,
    blur_bin_edges,
    fit_binned,
    fit_binned_blur,
    fit_confidence,
)
from pdcov.detection.tracks import (
    MOT_DEFAULT_CLASSES,
    TRACK_FORMATS,
    TrackedSet,
    read_tracked,
    tracked_format,
)
from pdcov.detection.truth_set import NO_BOXES, Boxes, ImageTruth
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


def _tracked_format(args: argparse.Namespace) -> str | None:
    """The tracked-sequence format of the inputs, or None for a labelled image set."""
    if args.format in TRACK_FORMATS:
        return str(args.format)
    return tracked_format(args.ground_truth) if args.format is None else None


def _read_tracked(args: argparse.Namespace, fmt: str,
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


def _frames(args: argparse.Namespace, tracked: TrackedSet) -> Iterator[Any]:
    return iter(tqdm(tracked.frames, desc="matching", unit="frame", disable=args.quiet,
                     file=sys.stderr))


def _match(args: argparse.Namespace, settings: MatchSettings,
           blur_csv: Path | None = None, speed: SpeedToBlur | None = None) -> Matches:
    """The matches of the set; with each image's blur when ``blur_csv`` is given."""
    fmt = _tracked_format(args)
    if fmt is not None:  # every frame an image
        tracked, settings = _read_tracked(args, fmt, settings)
        return match_images(((f.truth, f.detections) for f in _frames(args, tracked)),
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
    fmt = _tracked_format(args)
    looks_fit = None
    if fmt is not None:
        if args.model != "binned":
            raise ConfigError("--model logistic: tracked sequences are fitted with the binned "
                              "model (the correlation of the looks is estimated per bin)")
        if args.blur_csv is not None:
            raise ConfigError("--blur-csv: blur tables are fitted on labelled image sets, "
                              "not on tracked sequences")
        tracked, settings = _read_tracked(args, fmt, settings)
        matches, looks = collect_looks(_frames(args, tracked), len(tracked.people), settings)
    else:
        matches = _match(args, settings, args.blur_csv, speed)
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


def format_model_table(model: DetectorModel) -> str:
    """Per-bin table: size range, P_D with its interval and counts, the paper's 1 -
    precision likewise, and the false boxes per frame per Mpx (what the grid uses)."""
    ci_d = model.extra.get("p_detect_ci95")
    ci_fa = model.extra.get("p_false_alarm_ci95")
    ci_rate = model.extra.get("fa_rate_per_mpx_ci95")
    rate = model.fa_rate_per_mpx
    c = model.counts
    rows = [f"{'size px':>15} {'N_true':>7} {'N_det':>7} {'P_D':>6} {'95% CI':>15} "
            f"{'N_total':>7} {'1-prec':>6} {'95% CI':>15} {'FA/Mpx':>8} {'95% CI':>19}"]
    for i in range(model.n_bins):
        lo, hi = model.bin_edges_px[i], model.bin_edges_px[i + 1]
        rows.append(
            f"{lo:7.1f}-{hi:<7.1f} "
            f"{c.n_true[i] if c else '':>7} {c.n_detected[i] if c else '':>7} "
            f"{model.p_detect[i]:6.3f} {_ci(ci_d, i):>15} "
            f"{c.n_detections[i] if c else '':>7} {model.p_false_alarm[i]:6.3f} "
            f"{_ci(ci_fa, i):>15} {f'{rate[i]:8.4g}' if rate else '':>8} "
            f"{_ci_rate(ci_rate, i):>19}")
    return "\n".join(rows)


def _ci_rate(ci: list[list[float]] | None, i: int) -> str:
    return f"[{ci[i][0]:.3g}, {ci[i][1]:.3g}]" if ci else ""


LOOKS_EXAMPLE = 20  # looks for the "found within n looks" column of the looks table


def format_looks_table(model: DetectorModel, fit: LooksFit) -> str:
    """Per bin: people and looks, the beta-binomial mean P_D and correlation with their
    intervals, the p-value of independence, and the share found within 20 looks by the
    independent and by the fitted model; then the bins without an estimate."""
    n = LOOKS_EXAMPLE
    rows = [f"{'size px':>15} {'people':>6} {'looks':>7} {'mean P_D':>8} {'95% CI':>15} "
            f"{'rho':>6} {'95% CI':>15} {'p indep':>8} {f'{n} looks: indep':>16} "
            f"{'fitted':>6}"]
    missing = []
    for i, b in enumerate(fit.bins):
        lo, hi = model.bin_edges_px[i], model.bin_edges_px[i + 1]
        head = f"{lo:7.1f}-{hi:<7.1f} {b.n_people:6d} {b.n_looks:7d} "
        if not b.estimated:
            rows.append(head + f"{'-':>8} {'':>15} {'-':>6}   no estimate: {b.reason}")
            missing.append(i)
            continue
        indep, fitted = (float(found_within(n, b.mean_pd, r)) for r in (0.0, b.correlation))
        rows.append(head + f"{b.mean_pd:8.3f} {_ci([list(b.mean_pd_ci95)], 0):>15} "
                    f"{b.correlation:6.3f} {_ci([list(b.correlation_ci95)], 0):>15} "
                    f"{b.p_value_independent:8.2g} {indep:16.5f} {fitted:6.3f}")
    rows.append("mean P_D and rho (intra-person correlation) of a beta-binomial per-person "
                "detectability, profile-likelihood 95 % intervals; p indep: likelihood-ratio "
                "test of independent looks (rho = 0), chi-bar-square")
    if missing:
        rows.append(f"no estimate in {len(missing)} of {len(fit.bins)} bins: the engine takes "
                    f"their looks as independent (rho = 0), which may overstate coverage")
    return "\n".join(rows)


def format_blur_table(model: DetectorModel) -> str:
    """P_D by blur bin (rows) and size bin (columns), with each cell's object count."""
    blur = model.blur
    assert blur is not None
    n_true = blur.extra.get("n_true")
    head = " ".join(f"{model.bin_edges_px[i]:>6.1f}+" for i in range(model.n_bins))
    rows = ["P_D by blur (rows) and size (columns, from px):", f"{'blur px':>13} {head}"]
    for j, row in enumerate(blur.p_detect):
        lo, hi = blur.edges_px[j], blur.edges_px[j + 1]
        rows.append(f"{lo:6.2f}-{hi:<6.2f} " + " ".join(f"{p:7.3f}" for p in row)
                    + (f"   (objects {sum(n_true[j])})" if n_true else ""))
    return "\n".join(rows)


def format_confidence_table(model: DetectorModel) -> str:
    """The evidence of a box's confidence, log(f_TP / f_FP), by size bin (rows) and
    confidence bin (columns), with each size bin's true and false boxes."""
    conf = model.confidence
    assert conf is not None
    n_tp = conf.extra.get("n_true_positives")
    n_fp = conf.extra.get("n_false_positives")
    lr = conf.log_lr_table()
    head = " ".join(f"{e:>6.3g}+" for e in conf.edges[:-1])
    rows = [f"confidence evidence log(f_TP / f_FP) by size (rows) and confidence (columns, "
            f"from), {conf.extra.get('smoothing', 'as given')} smoothing:",
            f"{'size px':>15} {'TP':>6} {'FP':>6} {head}"]
    for i in range(model.n_bins):
        lo, hi = model.bin_edges_px[i], model.bin_edges_px[i + 1]
        counts = (f"{sum(n_tp[i]):6d} {sum(n_fp[i]):6d}" if n_tp and n_fp
                  else f"{'':6} {'':6}")
        rows.append(f"{lo:7.1f}-{hi:<7.1f} {counts} " + " ".join(f"{v:7.2f}" for v in lr[i]))
    return "\n".join(rows)


def _ci(ci: list[list[float]] | None, i: int) -> str:
    return f"[{ci[i][0]:.3f}, {ci[i][1]:.3f}]" if ci else ""


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
    matches = _match(args, settings)
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


def format_validation_table(report: ValidationReport) -> str:
    """Per-bin observed and predicted counts with p-values: detections among objects (P_D),
    true among detections (precision, the paper's 1 - P_FA), and false boxes with their rate
    per frame per Mpx (the grid's P_FA); then the number of bins failing."""
    rows = [f"{'size px':>15} {'N_true':>7} {'det':>6} {'pred':>8} {'p':>8}   "
            f"{'N_total':>7} {'TP':>6} {'pred':>8} {'p':>8}   "
            f"{'FP':>6} {'pred':>8} {'FA/Mpx':>8} {'95% CI':>19} {'p':>8}"]

    def p(v: float | None) -> str:
        return "-" if v is None else f"{v:.3g}" + ("*" if v < report.alpha else "")

    for i, (d, q) in enumerate(zip(report.detect, report.precision, strict=True)):
        lo, hi = report.bin_edges_px[i], report.bin_edges_px[i + 1]
        row = (f"{lo:7.1f}-{hi:<7.1f} {d.n:7d} {d.observed:6d} {d.expected:8.1f} "
               f"{p(d.p_value):>8}   {q.n:7d} {q.observed:6d} {q.expected:8.1f} "
               f"{p(q.p_value):>8}")
        if report.fa_rate:
            r = report.fa_rate[i]
            pred = "-" if r.expected is None else f"{r.expected:8.1f}"
            row += (f"   {r.observed:6d} {pred:>8} {r.rate_per_mpx:8.4g} "
                    f"{_ci_rate([list(r.rate_ci95)], 0):>19} {p(r.p_value):>8}")
        rows.append(row)
    fd, nd = report.n_failed("detect")
    fp, np_ = report.n_failed("precision")
    fr, nr = report.n_failed("fa_rate")
    test = {"binomial": "exact binomial", "chi2": "chi-square", "fisher": "Fisher exact"}[
        report.test]
    rate = (f", false boxes per Mpx in {fr} of {nr} bins ("
            f"{'two-sample Poisson' if report.test == 'fisher' else 'exact Poisson'})"
            if nr else "")
    rows.append(f"{test} tests, * p < {report.alpha:g}: P_D fails in {fd} of {nd} bins, "
                f"precision in {fp} of {np_} bins{rate}")
    if not report.fa_rate:
        rows.append("false boxes per Mpx not measured: the images' sizes are unknown "
                    "(--sizes FILE or --images DIR)")
    elif not nr:
        rows.append("false boxes per Mpx not tested: the model's rate (fa_rate_per_mpx, "
                    "version 4) is compared on the model's own bins only"
                    + (", with the fit's counts for --test fisher"
                       if report.test == "fisher" else ""))
    return "\n".join(rows)


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
