"""The web map in a real headless browser (Debian's chromium driven by Selenium through
chromium-driver): the page loads from pdcov's own server at the address it printed (its
access token included), takes the token out of the address bar, keeps it in an HttpOnly,
SameSite=Strict cookie, updates live, and shows the coverage the publisher's grid has.
Skipped when chromium or its driver is absent."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time

import pytest
from chromium import wait_for
from watch_fixtures import DEMO, TinyPublisher, ZenohTinyDaemon, free_port, zenoh_conf

pytestmark = pytest.mark.e2e

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
        # The map was drawn: the canvas has coloured (heat map) pixels.
        coloured = browser.execute_script("""
            const c = document.getElementById('map'), d = c.getContext('2d')
              .getImageData(0, 0, c.width, c.height).data;
            let n = 0; for (let i = 0; i < d.length; i += 4) if (d[i+3] > 0) n++;
            return n;""")
        assert coloured > 1000
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
