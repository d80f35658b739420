"""``pdcov detector fit`` on tracked sequences (MOTChallenge layout): the reader
(detection/tracks.py) and its errors, and the fit recovering a known per-person
detectability from generated sequences (tests/support/mot_fixtures.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pdcov.core.detector import DetectorModel
from pdcov.detection.looks_fit import collect_looks, fit_looks
from pdcov.detection.matching import MatchSettings
from pdcov.detection.tracks import read_tracked, tracked_format
from pdcov.errors import InputFileError
from tests.support.mot_fixtures import TrueLooks, write_mot

EDGES = (8.0, 16.0, 32.0, 48.0)
MEANS = (0.3, 0.6, 0.85)
PEDESTRIANS = MatchSettings(classes=("pedestrian",))


def sequence(root: Path, gt: str, det: str, seqinfo: str | None = "seqLength=5") -> Path:
    """One sequence folder SEQ under root with these gt.txt and det.txt lines."""
    seq = root / "SEQ"
    (seq / "gt").mkdir(parents=True)
    (seq / "det").mkdir()
    (seq / "gt" / "gt.txt").write_text(gt)
    (seq / "det" / "det.txt").write_text(det)
    if seqinfo is not None:
        (seq / "seqinfo.ini").write_text(
            f"[Sequence]\nname=SEQ\nimWidth=1920\nimHeight=1080\n{seqinfo}\n")
    return root


def fit_folder(root: Path, fmt: str = "mot"):
    tracked = read_tracked(root, root, fmt)
    matches, looks = collect_looks(tracked.frames, len(tracked.people), PEDESTRIANS)
    return tracked, matches, looks, fit_looks(looks, EDGES)


def test_looks_follow_each_id_through_its_frames(tmp_path):
    # id 1 in frames 1, 2, 5 (a gap), detected in 2 and 5; id 2 (consider 0) ignored, with a
    # detection on it that is neither true nor false; id 3 a static person: a distractor.
    gt = ("1,1,100,100,60,120,1,1,1.0\n2,1,102,100,60,120,1,1,1.0\n"
          "5,1,110,100,60,120,1,1,0.5\n1,2,500,100,60,120,0,1,1.0\n"
          "1,3,900,100,60,120,1,7,1.0\n")
    det = ("2,-1,101,101,60,120,0.9,-1,-1,-1\n5,-1,111,99,60,120,0.8,-1,-1,-1\n"
           "1,-1,500,100,60,120,0.9,-1,-1,-1\n1,-1,1500,800,60,120,0.7,-1,-1,-1\n")
    tracked, matches, looks, _ = fit_folder(sequence(tmp_path, gt, det))
    assert tracked.people == ("SEQ:1", "SEQ:2", "SEQ:3")
    assert len(tracked.frames) == 5 and tracked.n_track_gaps == 1
    assert looks.person.tolist() == [0, 0, 0] and looks.hit.tolist() == [False, True, True]
    # 60 x 120 image px at 640 / 1920: sqrt(20 * 40) input px
    assert looks.size_px == pytest.approx(np.full(3, np.sqrt(800)))
    assert matches.status_counts["truth_ignored"] == 2
    assert matches.status_counts["detection_on_ignored_truth"] == 1
    assert matches.status_counts["detection_false"] == 1


def test_visdrone_mot_columns_and_results_folder(tmp_path):
    gt = "1,7,100,100,60,120,1,1,0,0\n2,7,100,100,60,120,1,1,0,0\n1,0,0,0,50,50,0,0,0,0\n"
    root = sequence(tmp_path / "seqs", gt, "", seqinfo="seqLength=2")
    results = tmp_path / "results"
    results.mkdir()
    (results / "SEQ.txt").write_text("1,-1,100,100,60,120,0.9,1,-1,-1\n"
                                     "2,-1,100,100,60,120,0.3,1,-1,-1\n")
    tracked = read_tracked(root, results, "visdrone-mot")
    assert tracked.people == ("SEQ:7",)
    assert tracked.frames[0].truth.ignore_regions_xywh.tolist() == [[0, 0, 50, 50]]
    _, looks = collect_looks(tracked.frames, 1, MatchSettings(classes=("pedestrian",)))
    assert looks.hit.tolist() == [True, False]  # 0.3: below the confidence threshold


def test_visdrone_mot_split_in_its_own_layout(tmp_path):
    split = tmp_path / "VisDrone2019-MOT-val"
    (split / "annotations").mkdir(parents=True)
    (split / "sequences" / "uav0001").mkdir(parents=True)
    (split / "annotations" / "uav0001.txt").write_text(
        "1,3,10,10,30,60,1,1,0,0\n2,3,12,10,30,60,1,1,0,0\n")
    Image.new("RGB", (1360, 765)).save(split / "sequences" / "uav0001" / "0000001.jpg")
    results = tmp_path / "results"
    results.mkdir()
    (results / "uav0001.txt").write_text("2,-1,12,10,30,60,0.8,1,-1,-1\n")
    assert tracked_format(split) == "visdrone-mot" and tracked_format(results) is None
    tracked = read_tracked(split, results, "visdrone-mot")
    assert tracked.sequences == ("uav0001",) and len(tracked.frames) == 2
    assert (tracked.frames[0].truth.width_px, tracked.frames[0].truth.height_px) == (1360, 765)
    _, looks = collect_looks(tracked.frames, 1, PEDESTRIANS)
    assert looks.hit.tolist() == [False, True]
    # 30 x 60 image px at 640 / 1360
    assert looks.size_px == pytest.approx(np.full(2, np.sqrt(1800) * 640 / 1360))


@pytest.mark.parametrize("gt, det, message", [
    ("1,1,1,1,10,10,1,1\n", "", r"gt\.txt:1: expected 'frame,id,left,top,width,height"),
    ("1,1,1,1,10,x,1,1,1\n", "", r"gt\.txt:1: expected numbers"),
    ("1,1,1,1,10,10,1,1,1\n1,1,1,1,-4,10,1,1,1\n", "", r"gt\.txt:2: negative box width"),
    ("2,1,1,1,10,10,1,1,1\n1,1,1,1,10,10,1,1,1\n", "",
     r"gt\.txt:2: id 1 in frame 1 after frame 2 \(.*gt\.txt:1\); a track's lines must be in"),
    ("2,1,1,1,10,10,1,1,1\n2,1,5,1,10,10,1,1,1\n", "", r"gt\.txt:2: .*once per frame"),
    ("0,1,1,1,10,10,1,1,1\n", "", r"gt\.txt:1: frame must be an integer >= 1"),
    ("9,1,1,1,10,10,1,1,1\n", "", r"gt\.txt:1: frame 9 beyond the sequence's 5 frames"),
    ("1,1.5,1,1,10,10,1,1,1\n", "", r"gt\.txt:1: id must be an integer"),
    ("1,1,1,1,10,10,1,14,1\n", "", r"gt\.txt:1: MOT class must be 1\.\.12"),
    ("1,1,1,1,10,10,1,1,1\n", "1,-1,1,1,10,10,1.5,-1,-1,-1\n",
     r"det\.txt:1: detection score 1\.5 outside \[0, 1\]"),
    ("1,1,1,1,10,10,1,1,1\n", "1,-1,1,1,10,-10,0.5\n", r"det\.txt:1: negative box"),
])
def test_malformed_lines_name_file_and_line(tmp_path, gt, det, message):
    root = sequence(tmp_path, gt, det)
    with pytest.raises(InputFileError, match=message):
        read_tracked(root, root)


def test_missing_ground_truth_detections_and_sizes(tmp_path, pdcov):
    root = sequence(tmp_path / "a", "1,1,1,1,10,10,1,1,1\n", "")
    (root / "SEQ" / "det" / "det.txt").unlink()
    with pytest.raises(InputFileError, match=r"SEQ: no detections for sequence 'SEQ' "
                                             r"\(looked for .*det/det\.txt"):
        read_tracked(root, root)
    (root / "OTHER").mkdir()
    with pytest.raises(InputFileError, match=r"OTHER: sequence without ground truth"):
        read_tracked(root, root)
    root = sequence(tmp_path / "b", "1,1,1,1,10,10,1,1,1\n", "", seqinfo=None)
    status, _, err = pdcov("detector", "fit", "--ground-truth", root, "--detections", root,
                           "--out", tmp_path / "m.yaml", "--quiet")
    assert status == 2 and "image size of sequence 'SEQ' unknown" in err
    assert not (tmp_path / "m.yaml").exists()


def test_cli_fit_writes_a_model_with_looks_and_the_looks_plot(tmp_path, pdcov):
    truth = TrueLooks(EDGES, MEANS, (0.3, 0.3, 0.3))
    root = write_mot(tmp_path / "mot", truth, n_people=400, seed=4, fa_per_frame=1.0)
    model_path = tmp_path / "detector.yaml"
    status, out, err = pdcov("detector", "fit", "--ground-truth", root, "--detections", root,
                             "--bins", "4,8,16,32,48", "--out", model_path, "--quiet")
    assert status == 0, err
    assert "p indep" in out and "no estimate in 1 of 4 bins" in out
    model = DetectorModel.from_yaml(model_path)
    assert model.to_dict()["version"] == 5 and model.looks is not None  # 5: confidence
    lk = model.looks
    assert lk.correlation[0] == 0.0 and not lk.extra["estimated"][0]  # 4-8 px: nobody
    assert lk.extra["estimated"][1:] == [True] * 3
    assert all(0.15 < r < 0.45 for r in lk.correlation[1:])
    assert lk.extra["test"] == "lrt-chibar2"
    assert lk.extra["tracks"]["n_people"] == 400 and lk.extra["tracks"]["n_sequences"] == 2
    assert sum(lk.extra["n_looks"]) == sum(model.counts.n_true)
    assert model.extra["fit"]["classes"] == ["pedestrian"]
    assert all(p > 0 for p in model.p_false_alarm[1:])  # the false alarms are counted

    fig, looks_fig = tmp_path / "fig6.png", tmp_path / "looks.png"
    status, out, err = pdcov("detector", "plot", model_path, "--out", fig,
                             "--looks", looks_fig)
    assert status == 0, err
    with Image.open(looks_fig) as im:
        assert im.format == "PNG"
        assert len(np.unique(np.asarray(im.convert("RGB")).reshape(-1, 3), axis=0)) > 50
