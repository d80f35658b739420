"""The web map in a real headless browser (Debian's chromium driven by Selenium through
chromium-driver): the page loads from pdcov's own server at the address it printed (its
access token included), takes the token out of the address bar, keeps it in an HttpOnly,
SameSite=Strict cookie, updates live, and shows the coverage the publisher's grid has.
Skipped when chromium or its driver is absent."""

from __future__ import annotations

import math
import re
import signal
import sqlite3
import subprocess
import sys
import time

import numpy as np
import pymap3d
import pytest

from pdcov.core.domain import GridGeometry
from pdcov.core.geodesy import Origin
from pdcov.ground.basemap import open_basemap
from pdcov.ground.fleet_merge import block_max_pd
from pdcov.ground.map_layers import rings_lat_lon
from pdcov.ground.web import blocks_payload
from pdcov.ground.web_auth import WebAccess, served_names
from tests.support.chromium import console_errors, requested_urls, wait_for
from tests.support.watch_fixtures import (
    DEMO,
    ThreadedWebMap,
    TinyPublisher,
    ZenohTinyDaemon,
    free_port,
    zenoh_conf,
)

zenoh = pytest.importorskip("zenoh")
pytest.importorskip("selenium.webdriver")

def coverage(driver) -> tuple[str, str, int]:
    el = driver.find_element("id", "coverage")
    return el.text, el.get_attribute("data-share"), int(el.get_attribute("data-version") or -1)


def test_web_map_shows_live_coverage(browser, tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(zenoh_conf("router", listen=endpoint))
    daemon = None
    watch = None
    try:
        daemon = ZenohTinyDaemon(TinyPublisher("uav1"), endpoint)
        daemon.publish_step(3)
        port = free_port()
        watch = subprocess.Popen(
            [sys.executable, "-m", "pdcov.cli", "watch", "--mode", "client", "--zenoh-connect",
             endpoint, "--no-multicast-scouting", "--plain", "--web", f"127.0.0.1:{port}",
             "--config", DEMO],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        line = watch.stdout.readline()
        m = re.search(rf"web map at (http://127\.0\.0\.1:{port}/)\?token=(\S+)$",
                      line.strip())
        assert m, line
        base, token = m.groups()
        browser.get(base)  # without the token: the short explanation, no map
        assert "needs its access token" in browser.find_element("tag name", "body").text
        browser.get(f"{base}?token={token}")
        first = wait_for(lambda: coverage(browser)[1] and coverage(browser), 30,
                         "the first update")
        for _ in range(20):
            daemon.publish_step()
            time.sleep(0.1)
        # A live update: the shown coverage grows without reloading the page.
        later = wait_for(lambda: (c := coverage(browser))[2] > first[2] and
                         float(c[1]) > float(first[1]) and c, 30, "a live update")
        time.sleep(2.0)  # nothing new flies: the page settles on the final figures
        text, share, _ = coverage(browser)
        expected = daemon.pub.grid.metrics([0.8]).proportion_at_or_above[0.8]
        assert float(share) == pytest.approx(expected, abs=1e-12)
        assert text == f"{100 * expected:.1f} %"
        assert re.fullmatch(r"\d+\.\d %", later[0])
        rows = browser.find_elements("css selector", "#vehicles tr[data-vehicle]")
        assert [r.get_attribute("data-vehicle") for r in rows] == ["uav1"]
        # The open bus is named on the page, all the time (docs/ground-station.md
        # "Securing the bus").
        warnings = browser.find_element("id", "warnings")
        assert warnings.is_displayed() and "bus not secured" in warnings.text
        # The map was drawn: the heat map's image is on the map, made from the state.
        wait_for(lambda: browser.execute_script(
            "return document.getElementById('map').dataset.heatVersion"), 30, "the heat map")
        assert browser.execute_script(
            "return document.querySelectorAll('img.pd-layer').length") == 1
        # The token left the address bar (not in screenshots or shared links) and lives
        # on in a cookie the page's scripts cannot read.
        assert browser.current_url == base
        assert browser.execute_script("return document.cookie") == ""
        (cookie,) = browser.get_cookies()
        assert cookie["name"] == f"pdcov_watch_token_{port}" and cookie["value"] == token
        assert cookie["httpOnly"] is True and cookie["sameSite"] == "Strict"
        browser.refresh()  # the cookie alone opens the map again
        wait_for(lambda: coverage(browser)[1], 30, "the map after a reload")
        assert browser.current_url == base
        shot = tmp_path / "web-map.png"
        browser.save_screenshot(str(shot))
        assert shot.stat().st_size > 10_000
    finally:
        if watch is not None:
            watch.send_signal(signal.SIGTERM)
            try:
                watch.wait(timeout=30)
            except subprocess.TimeoutExpired:
                watch.kill()
                watch.wait(timeout=10)
        if daemon is not None:
            daemon.close()
        router.close()


# -- the Leaflet map on a state made here (no bus): basemap, layers, candidates ------------

ORIGIN = Origin(47.397742, 8.545594, 488.0)
GEOMETRY = GridGeometry(-30.0, -20.0, 1.0, 40, 60)  # 60 m east by 40 m north
TOKEN = "leaflet-test-token-0123456789abcdef"
ZOOM = 17


def tile_xy(lat_deg: float, lon_deg: float, z: int) -> tuple[int, int]:
    """The XYZ tile (y from the north) holding a point (the OpenStreetMap formula)."""
    n = 2 ** z
    lat = math.radians(lat_deg)
    return (int((lon_deg + 180) / 360 * n),
            int((1 - math.log(math.tan(lat) + 1 / math.cos(lat)) / math.pi) / 2 * n))


def tile_rgb(x: int, y: int) -> tuple[int, int, int]:
    """A colour of its own for each tile of the test basemap."""
    return (40 * (x % 6), 40 * (y % 6), 200)


def make_mbtiles(path, around: tuple[int, int]) -> None:
    """A 5 x 5 tile MBTiles file at ZOOM about the tile ``around``, rows in TMS order."""
    cv2 = pytest.importorskip("cv2")
    db = sqlite3.connect(path)
    db.executescript("CREATE TABLE metadata (name text, value text);"
                     "CREATE TABLE tiles (zoom_level integer, tile_column integer, "
                     "tile_row integer, tile_data blob);")
    db.executemany("INSERT INTO metadata VALUES (?, ?)",
                   [("name", "test area"), ("format", "png"), ("attribution", "<b>test</b>")])
    for x in range(around[0] - 2, around[0] + 3):
        for y in range(around[1] - 2, around[1] + 3):
            r, g, b = tile_rgb(x, y)
            ok, png = cv2.imencode(".png", np.full((256, 256, 3), (b, g, r), np.uint8))
            db.execute("INSERT INTO tiles VALUES (?, ?, ?, ?)",
                       (ZOOM, x, 2 ** ZOOM - 1 - y, png.tobytes()))
    db.commit()
    db.close()


def constructed_state(basemap: dict) -> dict:
    """A map state as map_state gives it, plus the candidates and gaps other parts add: the
    west half of the grid at P_D 0, the east half at 1, an obstacle in the south-west."""
    pd = np.zeros((GEOMETRY.n_rows, GEOMETRY.n_cols))
    pd[:, 30:] = 1.0
    mask = np.ones_like(pd, dtype=bool)
    mask[:5, :5] = False
    boundary = [[-30, -20], [30, -20], [30, 20], [-30, 20], [-30, -20]]
    obstacle = [[-30, -20], [-25, -20], [-25, -15], [-30, -15], [-30, -20]]
    boundary_ll, obstacle_ll = rings_lat_lon([boundary, obstacle], ORIGIN)
    track = rings_lat_lon([[[-25, 15], [0, 15], [20, 10]]], ORIGIN)[0]
    footprint = rings_lat_lon([[[15, 5], [25, 5], [25, 15], [15, 15], [15, 5]]], ORIGIN)[0]
    plan = rings_lat_lon([[[-25, 15], [25, 15], [25, -15], [-25, -15]]], ORIGIN)[0]
    gap = rings_lat_lon([[[-20, -10], [-10, -10], [-10, 0], [-20, 0], [-20, -10]]], ORIGIN)[0]
    (((lat, lon),),) = rings_lat_lon([[[10, 5]]], ORIGIN)

    def pin(cid: int, p_person: float, x_m: float, y_m: float) -> dict:
        (((lat_, lon_),),) = rings_lat_lon([[[x_m, y_m]]], ORIGIN)
        return {"id": cid, "uid": f"uav1.3fa2c1.{cid}", "class": "person", "lat_deg": lat_,
                "lon_deg": lon_, "sigma_m": 1.0, "p_person": p_person, "hits": 1,
                "looks": 3, "pd": 0.5, "pfa": 0.01, "confidence": 0.5,
                "first_t_boot_s": 100.0, "last_t_boot_s": 100.0}

    candidate = {"id": 1, "uid": "uav1.3fa2c1.1", "class": "person", "lat_deg": lat,
                 "lon_deg": lon, "sigma_m": 1.5, "p_person": 0.9731, "hits": 9, "looks": 14,
                 "pd": 0.87, "pfa": 0.02, "confidence": 0.71, "first_t_boot_s": 120.5,
                 "last_t_boot_s": 131.0}
    # Not in order on purpose: the page sorts (map_state sends the most probable first).
    pins = [pin(2, 0.05, -15, 10), candidate, pin(3, 0.6, 0, -10), pin(4, 0.3, 5, 5)]
    return {
        "version": 7,
        "fleet": {"target": 0.8, "thresholds": [0.8], "proportion": {"0.8": 0.5},
                  "mean_pd": 0.5, "merged": ["uav1"], "cells_free": 2375},
        "grid": blocks_payload(block_max_pd(pd, mask, 1), 1, GEOMETRY, ORIGIN, 0.8),
        "domain": {"source": "--config", "grid_hash": "h", "boundary": boundary,
                   "obstacles": [obstacle], "boundary_lat_lon": boundary_ll,
                   "obstacles_lat_lon": [obstacle_ll]},
        "domain_note": None,
        "plans": [{"source": "lawnmower.plan", "waypoints_lat_lon": plan}],
        "warnings": ["bus not secured (test)"],
        "vehicles": [{"id": "uav1", "color": "#e6194b", "alive": True, "grid_ready": True,
                      "link": "connected", "age_s": 0.3, "frames_used": 10,
                      "frames_skipped": 0, "proportion": {"0.8": 0.5},
                      "status_proportion": {"0.8": 0.5}, "mean_pd": 0.5,
                      "track_lat_lon": track, "footprint_lat_lon": footprint,
                      "candidates": pins}],
        "gaps": [gap],
        "origin": {"lat_deg": ORIGIN.lat_deg, "lon_deg": ORIGIN.lon_deg},
        "basemap": basemap,
    }


@pytest.fixture
def leaflet_page(browser, tmp_path):
    """The constructed state served with an MBTiles basemap, open in chromium (token)."""
    path = tmp_path / "area.mbtiles"
    make_mbtiles(path, tile_xy(ORIGIN.lat_deg, ORIGIN.lon_deg, ZOOM))
    basemap = open_basemap(path)
    state = constructed_state(basemap.info.as_json())
    served = ThreadedWebMap(lambda: state, WebAccess(TOKEN, served_names("127.0.0.1", "h")),
                            basemap)
    base = f"http://127.0.0.1:{served.web.port}/"
    try:
        browser.get(f"{base}?token={TOKEN}")
        wait_for(lambda: browser.execute_script(
            "return document.getElementById('map').dataset.heatVersion") == "7", 30,
            "the heat map drawn")
        wait_for(lambda: browser.execute_script(
            "return document.querySelectorAll('img.leaflet-tile-loaded').length") > 0, 30,
            "basemap tiles")
        yield browser, base
    finally:
        served.close()


def test_the_map_draws_the_basemap_and_loads_nothing_from_elsewhere(leaflet_page):
    browser, base = leaflet_page
    tiles = browser.execute_script("""
        return Array.from(document.querySelectorAll('img.leaflet-tile-loaded'), (img) => {
          const c = document.createElement('canvas'); c.width = c.height = 1;
          const cx = c.getContext('2d'); cx.drawImage(img, -128, -128);
          return [img.src, Array.from(cx.getImageData(0, 0, 1, 1).data)]; });""")
    for src, rgba in tiles:  # each tile is the one asked for (the TMS row flipped)
        m = re.fullmatch(rf"{re.escape(base)}basemap/{ZOOM}/(\d+)/(\d+)\.png", src)
        assert m, src
        assert rgba == [*tile_rgb(int(m[1]), int(m[2])), 255], (src, rgba)
    urls = requested_urls(browser)
    assert any(u.endswith("vendor/leaflet/leaflet.js") for u in urls), urls
    outside = [u for u in urls if not (u.startswith(base) or u.startswith("blob:" + base))]
    assert outside == [], outside
    resources = browser.execute_script(
        "return performance.getEntriesByType('resource').map((e) => e.name)")
    assert all(u.startswith((base, "blob:")) for u in resources), resources
    errors = [e for e in console_errors(browser) if "/basemap/" not in e]  # 404s outside
    assert errors == [], errors
    # The scale bar, the warnings banner, the attribution as text (not HTML).
    assert re.fullmatch(r"\d+ k?m", browser.find_element(
        "css selector", ".leaflet-control-scale-line").text)
    assert "bus not secured" in browser.find_element("id", "warnings").text
    assert "<b>test</b>" in browser.find_element(
        "css selector", ".leaflet-control-attribution").text
    assert browser.execute_script("return window.pdcov.controls.id") == "pdcov-controls"


def test_the_heat_map_lies_where_the_grid_is(leaflet_page):
    browser, _ = leaflet_page
    # The grid's corners by pymap3d directly, placed by Leaflet, against the image drawn.
    corners = [pymap3d.enu2geodetic(x, y, 0.0, ORIGIN.lat_deg, ORIGIN.lon_deg,
                                    ORIGIN.ground_alt_msl_m)[:2]
               for x, y in ((GEOMETRY.x0_m, GEOMETRY.y0_m),
                            (GEOMETRY.x0_m + 60, GEOMETRY.y0_m + 40))]
    placed, rect = browser.execute_script("""
        const m = window.pdcov.map, box = m.getContainer().getBoundingClientRect();
        const img = document.querySelector('img.pd-layer').getBoundingClientRect();
        return [arguments[0].map((c) => { const p = m.latLngToContainerPoint(c);
                                         return [p.x + box.left, p.y + box.top]; }),
                [img.left, img.bottom, img.right, img.top]];""", corners)
    (sw_x, sw_y), (ne_x, ne_y) = placed
    assert rect == pytest.approx([sw_x, sw_y, ne_x, ne_y], abs=1.0)
    assert ne_x - sw_x > 300  # zoomed in on the grid
    # Its pixels are the cells: P_D 0 west (viridis' first stop), 1 east (its last), the
    # obstacle grey, each in its place (row 0 of the image is the grid's north row).
    pixels = browser.execute_script("""
        const img = document.querySelector('img.pd-layer');
        const c = document.createElement('canvas'); c.width = img.naturalWidth;
        c.height = img.naturalHeight; const cx = c.getContext('2d'); cx.drawImage(img, 0, 0);
        return [[c.width, c.height], ...arguments[0].map(([x, y]) =>
          Array.from(cx.getImageData(x, y, 1, 1).data))];""",
        [[10, 10], [50, 10], [2, 37]])
    assert pixels[0] == [60, 40]
    for got, want in zip(pixels[1:], ([68, 1, 84, 215], [253, 231, 37, 215],
                                      [119, 119, 119, 170]), strict=True):
        assert got == pytest.approx(want, abs=1), pixels  # the canvas premultiplies alpha
    assert browser.execute_script(
        "return window.pdcov.layers.outline.getLayers().length") == 2


def test_layers_toggle_and_a_candidate_shows_its_numbers(leaflet_page):
    browser, _ = leaflet_page
    names = browser.execute_script("""return Array.from(document.querySelectorAll(
        '.leaflet-control-layers-overlays label'), (l) => l.textContent.trim());""")
    assert names == ["P_D heat map", "outline at the target P_D", "domain and obstacles",
                     "plan waypoints", "tracks", "footprints now", "detection candidates",
                     "gaps to re-fly", "re-fly path proposed", "basemap (test area)"]
    counts = browser.execute_script("""const L = window.pdcov.layers; return Object.fromEntries(
        Object.entries(L).map(([k, g]) => [k, g.getLayers().length]));""")
    assert counts == {"heat": 1, "outline": 2, "domain": 2, "plans": 5, "tracks": 2,
                      "footprints": 1, "candidates": 8, "gaps": 1, "refly": 0}

    def toggle(name):
        browser.execute_script("""Array.from(document.querySelectorAll(
            '.leaflet-control-layers-overlays label')).find((l) =>
            l.textContent.trim() === arguments[0]).querySelector('input').click();""", name)

    def heat_shown():
        return browser.execute_script(
            "return [window.pdcov.map.hasLayer(window.pdcov.layers.heat),"
            " document.querySelectorAll('img.pd-layer').length]")

    assert heat_shown() == [True, 1]
    toggle("P_D heat map")
    assert heat_shown() == [False, 0]
    toggle("basemap (test area)")
    assert browser.execute_script(
        "return document.querySelectorAll('img.leaflet-tile').length") == 0
    toggle("P_D heat map")
    assert heat_shown() == [True, 1]
    browser.find_element("css selector", '[data-candidate="uav1.3fa2c1.1"]').click()
    text = wait_for(lambda: "seen" in (t := browser.execute_script("""
        const p = document.querySelector('.leaflet-popup-content');
        return p ? p.innerText : '';""")) and t, 10, "the candidate's popup")
    assert "person uav1.3fa2c1.1 (uav1)" in text and "seen 14 times, detected 9" in text
    for figure in ("uid\nuav1.3fa2c1.1", "p_person\n0.9731", "looks\n14", "hits\n9",
                   "P_D (cell)\n0.870", "P_FA (cell)\n0.020", "confidence\n0.71",
                   "\u00b1 1.5 m", "120.5 s (boot)", "131.0 s (boot)"):
        assert figure in text, (figure, text)
    time.sleep(1.0)  # further updates (the same state) leave the popup open
    assert browser.find_elements("css selector", ".leaflet-popup-content")


def test_pins_are_listed_most_probable_first_unlikely_faint_and_filtered(leaflet_page):
    browser, _ = leaflet_page

    def listed():
        return browser.execute_script("""return Array.from(
            document.querySelectorAll('#pins li'), (li) => [li.dataset.uid,
            Number(li.dataset.pPerson), li.classList.contains('faint')]);""")

    def markers():
        return browser.execute_script("""return Array.from(
            document.querySelectorAll('[data-candidate]'), (m) => [m.dataset.candidate,
            Number(getComputedStyle(m).opacity), m.classList.contains('faint')]).sort();""")

    assert listed() == [["uav1.3fa2c1.1", 0.9731, False], ["uav1.3fa2c1.3", 0.6, False],
                        ["uav1.3fa2c1.4", 0.3, False], ["uav1.3fa2c1.2", 0.05, True]]
    assert browser.find_element("css selector", "#pins li").text == \
        "0.97 person uav1.3fa2c1.1 9/14 looks"
    shown = markers()
    assert [m[0] for m in shown] == [f"uav1.3fa2c1.{k}" for k in (1, 2, 3, 4)]
    faint = {uid: (opacity, cls) for uid, opacity, cls in shown}
    assert faint["uav1.3fa2c1.2"] == (pytest.approx(0.35), True)  # p_person 0.05 < 0.1
    assert faint["uav1.3fa2c1.1"] == (1.0, False)
    assert browser.execute_script("""return getComputedStyle(
        document.querySelector('#pins li.faint')).opacity""") == "0.35"
    want = {"0": [1, 2, 3, 4], "0.1": [1, 3, 4], "0.5": [1, 3], "0.9": [1]}
    for minimum, kept in want.items():
        browser.execute_script("""const s = document.getElementById('pin-filter');
            s.value = arguments[0]; s.dispatchEvent(new Event('change'));""", minimum)
        uids = [f"uav1.3fa2c1.{k}" for k in kept]
        assert wait_for(lambda uids=uids: sorted(u for u, *_ in listed()) == uids
                        and [m[0] for m in markers()] == uids, 10, f"the filter {minimum}")
        assert browser.find_element("id", "pins-note").text == f"{len(kept)} of 4 pins"
        assert browser.execute_script(
            "return window.pdcov.layers.candidates.getLayers().length") == 2 * len(kept)
    time.sleep(1.0)  # further updates (the same state) keep the filter
    assert [m[0] for m in markers()] == ["uav1.3fa2c1.1"]
