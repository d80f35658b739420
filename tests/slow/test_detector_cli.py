"""``pdcov detector fit | validate | plot`` end to end on synthetic sets in the three formats."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pdcov.core.detector import DetectorModel
from tests.support.labelled_sets import coco_set
from tests.support.synthetic_detections import EDGES, INPUT, P_D, synthetic_set, write_coco

BINS = ",".join(f"{e:g}" for e in EDGES)


def write_yolo(truth, dets, root: Path) -> tuple[Path, Path, Path, Path]:
    """Labels, predictions (with confidences), a sizes file and a names file."""
    (root / "labels").mkdir(parents=True)
    (root / "pred").mkdir()
    sizes, names = root / "sizes.txt", root / "names.txt"
    names.write_text("person\ncar\n")
    sizes.write_text("".join(f"{k}.jpg {t.width_px} {t.height_px}\n" for k, t in truth.items()))

    def lines(b, w, h, with_score):
        out = []
        for (x, y, bw, bh), lab, s in zip(b.xywh, b.labels, b.scores, strict=True):
            cols = [("person", "car").index(lab), (x + bw / 2) / w, (y + bh / 2) / h, bw / w,
                    bh / h] + ([s] if with_score else [])
            out.append(" ".join(repr(float(c)) if i else str(c) for i, c in enumerate(cols)))
        return "\n".join(out) + "\n"

    for k, t in truth.items():
        if len(t.boxes):  # images without objects have no label file
            (root / "labels" / f"{k}.txt").write_text(lines(t.boxes, t.width_px, t.height_px,
                                                            False))
        (root / "pred" / f"{k}.txt").write_text(lines(dets[k], t.width_px, t.height_px, True))
    return root / "labels", root / "pred", sizes, names


def write_visdrone(truth, dets, root: Path) -> tuple[Path, Path, Path]:
    """A split directory (annotations/, 'person' written as pedestrian), detections, sizes."""
    (root / "split" / "annotations").mkdir(parents=True)
    (root / "det").mkdir()
    sizes = root / "sizes.txt"
    sizes.write_text("".join(f"{k} {t.width_px} {t.height_px}\n" for k, t in truth.items()))
    for k, t in truth.items():
        (root / "split" / "annotations" / f"{k}.txt").write_text("".join(
            f"{x!r},{y!r},{w!r},{h!r},1,1,0,0\n" for x, y, w, h in t.boxes.xywh.tolist()))
        (root / "det" / f"{k}.txt").write_text("".join(
            f"{x!r},{y!r},{w!r},{h!r},{s!r},1,-1,-1\n"
            for (x, y, w, h), s in zip(dets[k].xywh.tolist(), dets[k].scores.tolist(),
                                       strict=True)))
    return root / "split", root / "det", sizes


@pytest.fixture(scope="module")
def train_and_val(tmp_path_factory):
    root = tmp_path_factory.mktemp("sets")
    for name, seed in (("train", 21), ("val", 22)):
        truth, dets = synthetic_set(seed=seed, n_per_bin=200)
        write_coco(truth, dets, root / f"{name}_gt.json", root / f"{name}_dt.json")
    return root


def test_fit_validate_plot(pdcov, train_and_val, tmp_path):
    d = train_and_val
    model_path = tmp_path / "detector.yaml"
    status, out, err = pdcov("detector", "fit", "--ground-truth", d / "train_gt.json",
                             "--detections", d / "train_dt.json", "--out", model_path,
                             "--bins", BINS, "--classes", "person", "--quiet")
    assert status == 0, err
    assert "N_true" in out and f"wrote {model_path}" in out
    model = DetectorModel.from_yaml(model_path)
    assert model.bin_edges_px == EDGES and model.input_size_px == INPUT
    assert model.counts.n_true == (200,) * 7
    assert model.extra["interval_method"] == "wilson"
    assert model.extra["fit"]["classes"] == ["person"]
    assert np.all(np.abs(np.array(model.p_detect) - P_D) < 0.15)
    assert "bin_edges_px: [8.0, 12.0" in model_path.read_text()  # flow style lists

    report = tmp_path / "report.json"
    status, out, err = pdcov("detector", "validate", model_path, "--ground-truth",
                             d / "val_gt.json", "--detections", d / "val_dt.json",
                             "--report", report, "--quiet")
    assert status == 0, err
    doc = json.loads(report.read_text())
    assert len(doc["bins"]) == 7 and doc["tested_detect"] == 7 and doc["test"] == "binomial"
    assert f"P_D fails in {doc['failed_detect']} of 7 bins" in out
    assert f"false boxes per Mpx in {doc['failed_fa_rate']} of 7 bins (exact Poisson)" in out
    assert doc["version"] == 2 and doc["tested_fa_rate"] == 7 and doc["failed_fa_rate"] <= 2
    assert doc["failed_detect"] <= 2  # same process: few bins should fail at 5 %
    assert all(b["n_true"] == 200 for b in doc["bins"])

    fig = tmp_path / "fig6.png"
    status, out, err = pdcov("detector", "plot", model_path, "--validation", report,
                             "--out", fig)
    assert status == 0, err
    with Image.open(fig) as im:
        assert im.format == "PNG" and im.size == (1500, 1350)  # three panels: with the rate
        # not blank: the bars are coloured
        pixels = np.asarray(im.convert("RGB")).reshape(-1, 3)
        assert len(np.unique(pixels, axis=0)) > 50


def test_three_formats_give_the_same_counts(pdcov, tmp_path):
    truth, dets = synthetic_set(seed=31, n_per_bin=60)
    write_coco(truth, dets, tmp_path / "gt.json", tmp_path / "dt.json")
    labels, pred, sizes, names = write_yolo(truth, dets, tmp_path / "yolo")
    split, det, vsizes = write_visdrone(truth, dets, tmp_path / "visdrone")
    runs = {
        "coco": ("--ground-truth", tmp_path / "gt.json", "--detections", tmp_path / "dt.json",
                 "--classes", "person"),
        "yolo": ("--ground-truth", labels, "--detections", pred, "--sizes", sizes,
                 "--names", names, "--classes", "person"),
        "visdrone": ("--ground-truth", split, "--detections", det, "--sizes", vsizes,
                     "--classes", "pedestrian"),
    }
    counts = {}
    for fmt, data in runs.items():
        out_path = tmp_path / f"{fmt}.yaml"
        status, _, err = pdcov("detector", "fit", *data, "--out", out_path, "--bins", BINS,
                               "--quiet")
        assert status == 0, (fmt, err)
        m = DetectorModel.from_yaml(out_path)
        counts[fmt] = (m.counts, m.extra["n_true_positives"])
    assert counts["coco"] == counts["yolo"] == counts["visdrone"]
    assert sum(counts["coco"][0].n_true) == 7 * 60


def test_logistic_and_automatic_bins(pdcov, train_and_val, tmp_path):
    d = train_and_val
    out_path = tmp_path / "logistic.yaml"
    status, out, err = pdcov("detector", "fit", "--ground-truth", d / "train_gt.json",
                             "--detections", d / "train_dt.json", "--out", out_path,
                             "--model", "logistic", "--logistic-degree", "2",
                             "--fine-bins", "32", "--quiet")
    assert status == 0, err
    m = DetectorModel.from_yaml(out_path)
    assert m.n_bins == 32 and m.extra["model"] == "logistic"
    assert m.extra["fit"]["bins"] == "quantile:20"
    # validate a fine-binned model on coarse bins chosen from the validation split
    status, out, err = pdcov("detector", "validate", out_path, "--ground-truth",
                             d / "val_gt.json", "--detections", d / "val_dt.json",
                             "--bins", "log:6", "--test", "chi2", "--quiet")
    assert status == 0, err
    assert "chi-square tests" in out and "of 6 bins" in out


@pytest.mark.parametrize("extra, message", [
    (("--classes", "pedestrain"), "'pedestrain' not among the classes"),
    (("--bins", "8,4,16"), "--bins: edges must be at least 2 strictly increasing"),
    (("--bins", "equal:5"), "--bins: expected comma-separated edges"),
    (("--input-size", "big"), "--input-size: expected a number of pixels or 'none'"),
])
def test_bad_options_exit_2_with_one_line(pdcov, train_and_val, tmp_path, extra, message):
    d = train_and_val
    status, out, err = pdcov("detector", "fit", "--ground-truth", d / "train_gt.json",
                             "--detections", d / "train_dt.json", "--out", tmp_path / "m.yaml",
                             "--quiet", *extra)
    assert status == 2 and message in err
    assert err.startswith("pdcov detector: error:") and err.count("\n") == 1


def test_malformed_detection_file_is_named(pdcov, tmp_path):
    truth, dets = synthetic_set(seed=41, n_per_bin=5)
    labels, pred, sizes, names = write_yolo(truth, dets, tmp_path)
    bad = sorted(pred.glob("*.txt"))[1]
    bad.write_text(bad.read_text() + "0 0.5 0.5 0.1\n")
    n_lines = len(bad.read_text().splitlines())
    status, _, err = pdcov("detector", "fit", "--ground-truth", labels, "--detections", pred,
                           "--sizes", sizes, "--out", tmp_path / "m.yaml", "--quiet")
    assert status == 2
    assert f"{bad}:{n_lines}: expected 'class cx cy w h confidence', got 4 fields" in err
    assert not (tmp_path / "m.yaml").exists()


def test_plot_without_validation_and_a_bad_report(pdcov, tmp_path):
    model = tmp_path / "m.yaml"
    model.write_text("version: 1\nbin_edges_px: [0, 10, 20]\np_detect: [0.0, 0.75]\n"
                     "p_false_alarm: [0.25, 0.5]\ncounts: {n_true: [0, 4], n_detected: [0, 3],"
                     " n_detections: [2, 6]}\n")  # an empty bin is drawn as 'no data'
    status, _, err = pdcov("detector", "plot", model, "--out", tmp_path / "f.png")
    assert status == 0, err
    assert (tmp_path / "f.png").stat().st_size > 0
    (tmp_path / "r.json").write_text('{"bins": []}')
    status, _, err = pdcov("detector", "plot", model, "--validation", tmp_path / "r.json",
                           "--out", tmp_path / "g.png")
    assert status == 2 and "r.json: not a pdcov validation report" in err


def test_fit_writes_the_confidence_histograms_of_a_labelled_set(pdcov, tmp_path):
    """tests/support/labelled_sets.py's COCO set: the person of image 1 (34.6 px) found at 0.9 and
    again at 0.7 (a duplicate: false), a false box at 0.6 beside it, a box below the
    threshold; a false box of 16 px (20 image px at 640 / 800) at 0.95 in image 2."""
    gt = coco_set(tmp_path)
    dt = tmp_path / "dt.json"
    dt.write_text(json.dumps([
        {"image_id": 1, "category_id": 1, "bbox": [10, 20, 30, 40], "score": 0.9},
        {"image_id": 1, "category_id": 1, "bbox": [10, 20, 30, 40], "score": 0.7},
        {"image_id": 1, "category_id": 1, "bbox": [300, 300, 30, 40], "score": 0.6},
        {"image_id": 1, "category_id": 1, "bbox": [200, 100, 30, 40], "score": 0.3},
        {"image_id": 2, "category_id": 1, "bbox": [100, 100, 20, 20], "score": 0.95}]))
    out_path = tmp_path / "m.yaml"
    status, out, err = pdcov("detector", "fit", "--ground-truth", gt, "--detections", dt,
                             "--out", out_path, "--bins", "10,30,60", "--classes", "person",
                             "--confidence-bins", "2", "--quiet")
    assert status == 0, err
    assert "confidence evidence log(f_TP / f_FP)" in out
    model = DetectorModel.from_yaml(out_path)
    conf = model.confidence
    assert model.to_dict()["version"] == 5 and conf.edges == (0.5, 0.75, 1.0)
    assert conf.extra["n_true_positives"] == [[0, 0], [0, 1]]
    assert conf.extra["n_false_positives"] == [[0, 1], [2, 0]]
    # Size bin [30, 60): true (0 + 1) / 3 / 0.25, (1 + 1) / 3 / 0.25; false 3 and 1.
    np.testing.assert_allclose(conf.tp_density[1], [4 / 3, 8 / 3], rtol=1e-5)
    np.testing.assert_allclose(conf.fp_density[1], [3.0, 1.0], rtol=1e-5)
    assert model.confidence_log_lr(34.6, 0.9) == pytest.approx(np.log(8 / 3), rel=1e-5)
