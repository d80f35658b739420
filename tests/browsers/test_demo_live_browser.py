"""`pdcov demo --live` watched in a headless chromium: the web map draws the live coverage
(tests/simulators/test_demo_live.py: the demo's processes)."""

from __future__ import annotations

import json
import time

import pytest

from tests.support.demo_run import Run, demo_args
from tests.support.watch_fixtures import free_port


def test_live_demo_in_a_headless_browser(tmp_path):
    from tests.support.chromium import CHROMEDRIVER, CHROMIUM, FLAGS, have_browser

    if not have_browser():
        pytest.skip("chromium and chromium-driver are not installed (.ci/run installs them)")
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    out = tmp_path / "demo"
    port = free_port()
    # Slow enough that the browser, started once the page is served, sees the whole climb
    # (the pattern takes ~47 s of simulated flight: ~12 s of wall time at 4x).
    demo = Run(demo_args(out, "--web", f"127.0.0.1:{port}", speed="4"), tmp_path)
    opts = Options()
    opts.binary_location = CHROMIUM
    for f in FLAGS:
        opts.add_argument(f)
    opts.add_argument(f"--user-data-dir={tmp_path / 'profile'}")
    driver = None
    readings: list[tuple[str, str, str, int]] = []
    mid_shot = tmp_path / "web-map-mid-flight.png"
    try:
        url = demo.wait_line(rf"web map at (http://127\.0\.0\.1:{port}/\?token=\S+)",
                             90).group(1)
        driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
        driver.set_page_load_timeout(30)
        driver.get(url)
        end = time.monotonic() + 300
        while demo.p.poll() is None and time.monotonic() < end:
            try:
                el = driver.find_element("id", "coverage")
                r = (el.text, el.get_attribute("data-share"),
                     el.get_attribute("data-mean-pd"), int(el.get_attribute("data-version")
                                                           or -1))
            except Exception:  # noqa: BLE001 - the page goes away when the demo ends
                break
            if r[1]:
                readings.append(r)
                if not mid_shot.exists() and 0.3 < float(r[1]) < 0.9:
                    driver.save_screenshot(str(mid_shot))
            time.sleep(0.3)
        assert demo.wait(120) == 0, "\n".join(demo.lines[-30:])
    finally:
        if driver is not None:
            driver.quit()
        demo.close()
    status = json.loads((out / "demo.json").read_text())["status"]["uav1"]
    shares = [float(r[1]) for r in readings]
    # Live: the figure climbed through several values without a reload, never going back.
    assert len(set(shares)) >= 5 and shares == sorted(shares), shares
    assert len({r[3] for r in readings}) >= 5
    text, share, mean_pd, _ = readings[-1]
    expected = status["proportion_at_or_above"]["0.8"]
    assert float(share) == expected
    assert text == f"{100 * expected:.1f} %"
    # The status carries mean_pd to 6 decimals (docs/protocol.md "full and brief statuses").
    assert float(mean_pd) == pytest.approx(status["mean_pd"], abs=5e-7)
    assert mid_shot.stat().st_size > 10_000
