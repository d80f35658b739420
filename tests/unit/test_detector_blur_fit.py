"""``pdcov detector fit --blur-csv``: P_D and P_FA by blur and size from a labelled set whose
images' blur (or speed and height) a sidecar CSV gives; bad rows named by file and line."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from pdcov import cli
from pdcov.core.detector import DetectorModel
from tests.support.synthetic_detections import (
    BLUR_EDGES,
    EDGES,
    IMAGE_W,
    INPUT,
    P_D,
    P_D_BY_BLUR,
    P_FA_BY_BLUR,
    synthetic_blur_set,
    write_coco,
)

BINS = ",".join(f"{e:g}" for e in EDGES)
BLUR_BINS = ",".join(f"{e:g}" for e in BLUR_EDGES)


@pytest.fixture(scope="module")
def blur_set(tmp_path_factory):
    root = tmp_path_factory.mktemp("blur")
    truth, dets, blur = synthetic_blur_set(seed=5, n_per_bin=300)
    write_coco(truth, dets, root / "gt.json", root / "dt.json")
    # By file name for most images, by file stem for some (both name a COCO image).
    rows = [f"{k}.jpg,{b!r}" if i % 3 else f"{k},{b!r}" for i, (k, b) in enumerate(blur.items())]
    (root / "blur.csv").write_text("image,blur_px\n" + "\n".join(rows) + "\n")
    return root, blur


def fit(root: Path, out: Path, csv: Path, *more: str) -> int:
    return cli.main(["detector", "fit", "--ground-truth", str(root / "gt.json"),
                     "--detections", str(root / "dt.json"), "--out", str(out), "--bins", BINS,
                     "--classes", "person", "--quiet", "--blur-csv", str(csv),
                     "--blur-bins", BLUR_BINS, *more])


def test_fit_recovers_the_known_tables_by_blur_and_size(blur_set, tmp_path, capsys):
    root, _ = blur_set
    out = tmp_path / "model.yaml"
    assert fit(root, out, root / "blur.csv") == 0
    printed = capsys.readouterr().out
    assert "P_D by blur (rows) and size (columns, from px)" in printed
    model = DetectorModel.from_yaml(out)
    b = model.blur
    assert b is not None and b.edges_px == BLUR_EDGES and model.input_size_px == INPUT
    assert b.extra["n_true"] == [[300] * 7] * 3 and b.extra["truth_outside_bins"] == 0
    misses = 0
    for key, truth in (("p_detect", P_D_BY_BLUR), ("p_false_alarm", P_FA_BY_BLUR)):
        lo, hi = np.moveaxis(np.array(b.extra[f"{key}_ci95"]), 2, 0)
        misses += int(((np.array(truth) < lo) | (np.array(truth) > hi)).sum())
    # 42 intervals of 95 %: more than 6 miss with probability < 1 %; a blur scaled or
    # assigned wrongly (image px not halved, a row shifted) misses most of a row.
    assert misses <= 6, misses
    # The 1-D tables are those of all images together: the mean of the three rows.
    assert np.abs(np.array(model.p_detect) - np.mean(P_D_BY_BLUR, axis=0)).max() < 0.06
    assert model.to_dict()["version"] == 5  # 5: confidence (4: fa_rate_per_mpx, 3: blur)
    assert np.array(b.p_detect)[0] == pytest.approx(np.array(P_D), abs=0.1)


def test_a_speed_column_becomes_blur_by_the_nadir_rule(blur_set, tmp_path):
    """speed_m_s and height_m with the set's focal length and exposure: blur = f v T / h,
    so speeds chosen to give the same blurs give the same tables."""
    root, blur = blur_set
    f_px, T, h = 1000.0, 0.004, 50.0
    rows = [f"{k}.jpg,{b * h / (f_px * T)!r},{h}" for k, b in blur.items()]
    csv = tmp_path / "speed.csv"
    csv.write_text("image,speed_m_s,height_m\n" + "\n".join(rows) + "\n")
    assert fit(root, tmp_path / "a.yaml", root / "blur.csv") == 0
    assert fit(root, tmp_path / "b.yaml", csv, "--focal-px", str(f_px),
               "--exposure-s", str(T)) == 0
    a, b = (DetectorModel.from_yaml(tmp_path / n).blur for n in ("a.yaml", "b.yaml"))
    assert a is not None and b is not None
    assert a.p_detect == b.p_detect and a.extra["n_true"] == b.extra["n_true"]
    assert b.extra["speed_to_blur"] == {"focal_px": f_px, "exposure_s": T}


@pytest.mark.parametrize(("text", "message"), [
    ("image,blur\n", r"blur.csv:1: expected the header image,blur_px or "
                     r"image,speed_m_s,height_m"),
    ("image,blur_px\nb0_img0000.jpg,1.0\nnope.jpg,2\n", r"blur.csv:3: image 'nope.jpg' is not"),
    ("image,blur_px\nb0_img0000.jpg,1.0\n\nb0_img0000,2\n", r"blur.csv:4: .* given twice"),
    ("image,blur_px\nb0_img0000.jpg,-1\n", r"blur.csv:2: blur_px: expected a finite number "
                                           r">= 0, got '-1'"),
    ("image,blur_px\nb0_img0000.jpg,fast\n", r"blur.csv:2: blur_px: .*'fast'"),
    ("image,blur_px\nb0_img0000.jpg,1,2\n", r"blur.csv:2: expected 2 values"),
    ("image,blur_px\nb0_img0000.jpg,1\n", r"blur.csv: no row for \d+ of the \d+ images"),
    ("image,speed_m_s,height_m\nb0_img0000.jpg,3,20\n", r"give --focal-px and --exposure-s"),
])
def test_bad_rows_are_named_by_file_and_line(blur_set, tmp_path, capsys, text, message):
    root, _ = blur_set
    csv = tmp_path / "blur.csv"
    csv.write_text(text)
    assert fit(root, tmp_path / "m.yaml", csv) != 0
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert re.search(message, err), err
    assert not (tmp_path / "m.yaml").exists()


def test_blur_bins_by_rule_start_at_zero(blur_set, tmp_path):
    root, blur = blur_set
    out = tmp_path / "q.yaml"
    assert cli.main(["detector", "fit", "--ground-truth", str(root / "gt.json"),
                     "--detections", str(root / "dt.json"), "--out", str(out), "--bins", BINS,
                     "--quiet", "--blur-csv", str(root / "blur.csv"),
                     "--blur-bins", "quantile:3"]) == 0
    b = DetectorModel.from_yaml(out).blur
    assert b is not None and b.edges_px[0] == 0.0 and len(b.edges_px) == 4
    assert b.edges_px[-1] > max(blur.values()) * INPUT / IMAGE_W
    assert b.extra["truth_outside_bins"] == 0
