"""report.html opened from disk in a real browser (Debian's chromium, headless): it asks for
nothing but itself, its images decode (the map and the heat map at their own pixels), the
pin table holds every candidate in rank order, and the page raises no console error."""

from __future__ import annotations

import json

from PIL import Image

from pdcov.report.handover import write_report
from tests.support.chromium import console_errors, requested_urls
from tests.support.handover_run import run_folder


def test_report_html_in_chromium_loads_nothing_else_and_shows_the_map_and_pins(tmp_path,
                                                                              browser):
    run = run_folder(tmp_path)
    Image.new("RGB", (300, 200), "white").save(run / "map.png")
    [html, *_], _ = write_report(run, run)
    url = html.resolve().as_uri()
    browser.get(url)
    images = browser.execute_script(
        "return [...document.images].map(i => [i.alt, i.complete, i.naturalWidth, "
        "i.naturalHeight])")
    assert sorted(images) == sorted([
        ["P_D map with the tracks and the numbered pins", True, 300, 200],
        ["P_D heat map", True, 120, 80]])
    rows = browser.execute_script(
        "const t = [...document.querySelectorAll('table')].find("
        "  t => t.querySelector('th') && t.querySelector('th').textContent === 'pin');"
        "return [...t.querySelectorAll('tbody tr')].map("
        "  r => [...r.cells].map(c => c.textContent));")
    feats = json.loads((run / "detections.geojson").read_text())["features"]
    ranked = sorted((f["properties"] for f in feats if f["properties"]["kind"] == "candidate"),
                    key=lambda p: p["rank"])
    assert [(r[0], r[1]) for r in rows] == [(str(p["rank"]), p["uid"]) for p in ranked]
    assert browser.title == "pdcov handover: alpha: <flight & 1>"
    # Only itself and its inline data: images; nothing over a network or from the disk.
    assert [u for u in requested_urls(browser) if u != url and not u.startswith(
        "data:image/png;base64,")] == []
    assert console_errors(browser) == []
