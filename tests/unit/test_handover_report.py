"""The handover report's page (report/handover.py) on fixture run files: self-contained,
the heat map inline, the pins by p_person with their MGRS, the thresholds of metrics.json,
every string escaped, missing pieces named, oversized files refused."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from pdcov.cli import main
from pdcov.errors import InputFileError
from pdcov.report import handover, run_files
from pdcov.report.handover import REPORT_HTML, write_report
from tests.support.handover_run import METRICS, run_folder
from tests.support.report_html import ReportPage, inline_png_size


def report_text(run, out) -> str:
    """report.html's text, written by write_report."""
    paths, _ = write_report(run, out)
    return paths[0].read_text()


def page(run, out=None) -> ReportPage:
    return ReportPage(report_text(run, out or run))


def test_page_is_self_contained_with_the_heat_map_inline(tmp_path):
    p = page(run_folder(tmp_path))
    assert p.external() == [] and p.references
    assert "script" not in p.tags and "link" not in p.tags
    [heat] = [i for i in p.images if i["alt"] == "P_D heat map"]
    assert inline_png_size(heat["src"]) == (120, 80)
    assert all(r.startswith("data:image/png;base64,") for r in p.references)


def test_pins_by_p_person_with_their_grid_references(tmp_path):
    run = run_folder(tmp_path)
    rows = page(run).table("pin")
    feats = json.loads((run / "detections.geojson").read_text())["features"]
    cands = sorted((f for f in feats if f["properties"]["kind"] == "candidate"),
                   key=lambda f: -f["properties"]["p_person"])
    assert len(rows) == len(cands) == 3
    for row, f in zip(rows, cands, strict=True):
        p, (lon, lat) = f["properties"], f["geometry"]["coordinates"]
        assert row == [str(p["rank"]), p["uid"], f"{p['p_person']:.3f}",
                       f"detected {p['hits']} of {p['looks']} looks", f"{lat:.7f}",
                       f"{lon:.7f}", p["mgrs"], p["utm"]]
    assert [float(r[2]) for r in rows] == sorted((float(r[2]) for r in rows), reverse=True)
    assert [r[0] for r in rows] == ["1", "2", "3"]


def test_thresholds_limiting_and_gaps_are_the_files(tmp_path):
    run = run_folder(tmp_path)
    p = page(run)
    assert {r[0]: float(r[1]) for r in p.table("P_D at or above")} == pytest.approx(
        METRICS["proportion_at_or_above"], abs=0.5e-4)
    assert p.table("limiting factor") == [["never in view", "857"], ["seen", "727"]]
    areas = [f["properties"] for f in json.loads((run / "caltopo.geojson").read_text())[
        "features"] if f["properties"]["class"] == "Assignment"]
    assert [r[:2] for r in p.table("letter")] == [[a["letter"], str(a["area_m2"])]
                                                  for a in areas] and areas
    files = [r[0] for r in p.table("file")]
    assert {"metrics.json", "heatmap.png", "caltopo.geojson", REPORT_HTML} <= set(files)


def test_strings_from_files_are_escaped(tmp_path):
    text = report_text(run_folder(tmp_path), tmp_path / "out")
    assert "<b>a warning</b>" not in text and "&lt;b&gt;a warning&lt;/b&gt;" in text
    assert "alpha: &lt;flight &amp; 1&gt;" in text and "<flight" not in text


def test_an_absent_figure_is_not_shown_and_a_present_one_is(tmp_path):
    assert "sweep width" not in report_text(run_folder(tmp_path), tmp_path)
    (tmp_path / "run").rename(tmp_path / "old")
    text = report_text(run_folder(tmp_path, {**METRICS, "sweep_width_m": 12.34}),
                        tmp_path)
    assert "effective sweep width</th><td>12.3 m" in text
    (tmp_path / "run").rename(tmp_path / "older")
    nested = {**METRICS, "sweep_width": {"sweep_width_m": 8.25, "note": "x"}}
    assert "sweep width m</th><td>8.25" in report_text(run_folder(tmp_path, nested),
                                                       tmp_path)


def test_missing_pieces_degrade_to_a_line(tmp_path):
    p = page(run_folder(tmp_path, exports=False, heatmap=None))
    text = report_text(tmp_path / "run", tmp_path / "run")
    assert p.images == [] and "heatmap.png is not in this run" in text
    assert "No detections.geojson" in text and "No caltopo.geojson" in text


def test_an_oversized_file_is_refused_naming_it(tmp_path, monkeypatch):
    run = run_folder(tmp_path)
    monkeypatch.setattr(run_files, "MAX_IMAGE_BYTES", 100)
    with pytest.raises(InputFileError, match="heatmap.png: .* over the report's limit"):
        write_report(run, run)


def test_command_writes_the_report_and_refuses_a_folder_that_is_no_run(tmp_path, capsys):
    run = run_folder(tmp_path)
    assert main(["report", str(run), "--out", str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / REPORT_HTML).is_file()
    assert main(["report", str(tmp_path / "out"), "--out", str(tmp_path / "x")]) == 2
    assert "no metrics.json" in capsys.readouterr().err


def test_a_fleets_vehicles_are_named(tmp_path):
    run = run_folder(tmp_path, {**METRICS, "vehicles": ["uav1", "uav2"]}, exports=False)
    assert ["vehicles", "uav1, uav2"] in page(run).tables[0]


def test_without_the_plots_extra_there_is_no_pdf_and_it_is_said(tmp_path, monkeypatch):
    monkeypatch.setattr(handover, "PLOTS", SimpleNamespace(message=lambda *a: "needs "
                                                                              "pdcov[plots]"))
    paths, missing = write_report(run_folder(tmp_path), tmp_path / "out")
    assert [p.name for p in paths] == [REPORT_HTML] and missing == "needs pdcov[plots]"
    assert not (tmp_path / "out" / "report.pdf").exists()
