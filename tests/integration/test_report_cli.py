"""``pdcov evaluate`` ends with the handover report in its run folder, and ``pdcov report
RUN --out DIR`` (a process) writes the same page elsewhere: self-contained, the run's own
heat map inline, its thresholds, every file of the run listed."""

from __future__ import annotations

import json

import pytest
from PIL import Image

from tests.support import evaluate_inputs as ev
from tests.support.report_html import ReportPage, inline_png_size


def test_evaluate_writes_the_report_and_the_command_the_same(tmp_path):
    config = ev.write_config(tmp_path, ev.mission_doc())
    csv = ev.write_pose_csv(tmp_path / "a.csv", ev.expected_poses(ev.known_flight(), None))
    out = tmp_path / "run"
    assert ev.run("evaluate", "--config", str(config), "--poses", str(csv), "--out", str(out),
               "--no-progress") == 0
    proc = ev.cli("report", str(out), "--out", str(tmp_path / "handover"))
    assert proc.returncode == 0, proc.stderr
    in_run = (out / "report.html").read_text()
    assert (tmp_path / "handover" / "report.html").read_text() == in_run
    page = ReportPage(in_run)
    assert page.external() == []
    [heat] = [i for i in page.images if i["alt"] == "P_D heat map"]
    with Image.open(out / "heatmap.png") as im:
        assert inline_png_size(heat["src"]) == im.size
    metrics = json.loads((out / "metrics.json").read_text())
    assert {r[0]: float(r[1]) for r in page.table("P_D at or above")} == pytest.approx(
        metrics["proportion_at_or_above"], abs=0.5e-4)
    listed = {r[0] for r in page.table("file")}
    assert listed == {p.name for p in out.iterdir() if not p.name.startswith(".")}
    assert "<h1>pdcov handover: uav1: a.csv</h1>" in in_run


def test_report_of_a_folder_that_is_no_run_fails_clearly(tmp_path):
    ev.assert_clean_failure(ev.cli("report", str(tmp_path), "--out", str(tmp_path / "o")),
                         "no metrics.json")
