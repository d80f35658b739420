"""``pdcov evaluate`` ends with the handover report in its run folder, and ``pdcov report
RUN --out DIR`` (a process) writes the same page elsewhere: self-contained, the run's own
heat map inline, its thresholds, every file of the run listed."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import numpy as np
import pytest
from PIL import Image

from pdcov.report.handover import REPORT_HTML, write_report
from tests.support import evaluate_inputs as ev
from tests.support.handover_run import run_folder
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
    assert metrics["time_on_scene_s"] > 0
    assert ["time on scene", f"{metrics['time_on_scene_s'] / 60:.1f} min"] in page.tables[0]
    listed = {r[0] for r in page.table("file")}
    assert listed == {p.name for p in out.iterdir() if not p.name.startswith(".")}
    assert "<h1>pdcov handover: uav1: a.csv</h1>" in in_run


def test_report_of_a_folder_that_is_no_run_fails_clearly(tmp_path):
    ev.assert_clean_failure(ev.cli("report", str(tmp_path), "--out", str(tmp_path / "o")),
                         "no metrics.json")


needs_poppler = pytest.mark.skipif(shutil.which("pdftotext") is None,
                                   reason="needs poppler's pdftotext and pdfinfo (apt-get "
                                          "install poppler-utils; .ci/run does)")


def poppler(*argv: str) -> str:
    return subprocess.run(argv, capture_output=True, text=True, check=True,
                          timeout=60).stdout


@needs_poppler
def test_report_pdf_is_read_by_poppler_with_the_pins_and_the_figures(tmp_path):
    run = run_folder(tmp_path)
    Image.new("RGB", (300, 200), "white").save(run / "map.png")
    paths, missing = write_report(run, run)
    assert missing is None and [p.name for p in paths] == [REPORT_HTML, "report.pdf"]
    info = poppler("pdfinfo", str(run / "report.pdf"))
    assert re.search(r"Page size:\s+595\.\d* x 841\.\d* pts \(A4\)", info)
    assert re.search(r"Title:\s+pdcov handover: alpha: <flight & 1>\n", info)
    text = poppler("pdftotext", "-layout", str(run / "report.pdf"), "-")
    feats = json.loads((run / "detections.geojson").read_text())["features"]
    for f in feats:
        if f["properties"]["kind"] == "candidate":
            p = f["properties"]
            assert re.search(rf"\b{p['rank']}\s+{re.escape(p['uid'])}\s+{p['p_person']:.3f}",
                             text), p["uid"]
            assert p["mgrs"] in text
    assert "0.4539" in text and "never in view" in text and "<b>a warning</b>" in text
    # map.png, heatmap.png: two images, at their pixel sizes.
    images = poppler("pdfimages", "-list", str(run / "report.pdf")).splitlines()[2:]
    assert sorted(tuple(map(int, row.split()[3:5])) for row in images) == [(120, 80),
                                                                           (300, 200)]


def magenta_tiles(folder, z: int, lat_deg: float, lon_deg: float, radius: int = 3) -> None:
    """An XYZ folder of plain magenta 256 px tiles at zoom ``z`` around a point."""
    from pdcov.report.map_figure import web_mercator_tile_xy

    tx, ty = (int(v) for v in web_mercator_tile_xy(np.array(lat_deg), np.array(lon_deg), z))
    for x in range(tx - radius, tx + radius + 1):
        (folder / str(z) / str(x)).mkdir(parents=True, exist_ok=True)
        for y in range(ty - radius, ty + radius + 1):
            Image.new("RGB", (256, 256), (255, 0, 255)).save(folder / str(z) / str(x) /
                                                              f"{y}.png")


def test_evaluate_draws_map_png_over_the_basemap_and_refuses_a_missing_one(tmp_path):
    config = ev.write_config(tmp_path, ev.mission_doc())
    csv = ev.write_pose_csv(tmp_path / "a.csv", ev.expected_poses(ev.known_flight(), None))
    tiles = tmp_path / "tiles"
    magenta_tiles(tiles, 19, ev.ORIGIN.lat_deg, ev.ORIGIN.lon_deg)
    out = tmp_path / "run"
    proc = ev.cli("evaluate", "--config", str(config), "--poses", str(csv), "--out", str(out),
                  "--basemap", str(tiles), "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "map.png's basemap" not in proc.stdout
    with Image.open(out / "map.png") as im:
        rgb = np.asarray(im.convert("RGB")).astype(int)
    # The margin round the domain shows the tiles unblended (a 1.2 m tile pixel at zoom 19
    # against the map's 5 cm pixel: the map is within the 7 x 7 tiles).
    magenta = (rgb[..., 0] > 240) & (rgb[..., 1] < 20) & (rgb[..., 2] > 240)
    assert magenta.sum() > 5_000
    page = ReportPage((out / "report.html").read_text())
    [shown] = [i for i in page.images if i["alt"].startswith("P_D map")]
    with Image.open(out / "map.png") as im:
        assert inline_png_size(shown["src"]) == im.size
    ev.assert_clean_failure(ev.cli("evaluate", "--config", str(config), "--poses", str(csv),
                                   "--out", str(tmp_path / "x"), "--basemap",
                                   str(tmp_path / "nowhere")), "--basemap", "no such file")


@needs_poppler
def test_a_title_in_another_script_reads_back_from_the_pdf(tmp_path):
    # Latin-1 text goes out in the standard PDF fonts; any other script in embedded DejaVu.
    from pdcov.report.handover import Handover, Section
    from pdcov.report.handover_pdf import write_handover_pdf

    for title, font in (("Поиск № 3 – ü", "DejaVuSans"), ("Search $3 to $5 – ü", "Helvetica")):
        pdf = write_handover_pdf(tmp_path / "r.pdf", Handover(
            title, (("run", title),), (Section("h", text=("…",)),)))
        assert f"pdcov handover: {title}" in poppler("pdftotext", str(pdf), "-")
        assert font in poppler("pdffonts", str(pdf))
