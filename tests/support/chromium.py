"""Debian's chromium driven by Selenium through chromium-driver, for the web map's tests: the
``browser`` fixture (a plugin of tests/conftest.py; a test using it is e2e), the browser's
paths and flags, and ``wait_for``. Skipped when chromium or its driver is absent (.ci/run
installs them)."""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--window-size=1280,900")


def have_browser() -> bool:
    return os.access(CHROMIUM, os.X_OK) and os.access(CHROMEDRIVER, os.X_OK)


@pytest.fixture
def browser(tmp_path) -> Iterator[Any]:
    if not have_browser():
        pytest.skip("chromium and chromium-driver are not installed (.ci/run installs them)")
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    opts = Options()
    opts.binary_location = CHROMIUM
    for f in FLAGS:
        opts.add_argument(f)
    opts.add_argument(f"--user-data-dir={tmp_path / 'chromium-profile'}")
    # Every request the page makes (DevTools Network events) and its console, for
    # requested_urls and console_errors.
    opts.set_capability("goog:loggingPrefs", {"performance": "ALL", "browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    driver.set_page_load_timeout(30)
    try:
        yield driver
    finally:
        driver.quit()


BROWSER_OWN = ("chrome://", "chrome-untrusted://")
"""URL schemes of chromium's own pages, never a page's request."""


def requested_urls(driver: Any) -> list[str]:
    """The URLs of every request made since the last call (DevTools
    Network.requestWillBeSent, blocked ones included), but those of chromium's own pages
    (chrome:// and chrome-untrusted://, e.g. the new tab page open before the test's:
    chromium 150 loads its parts from chrome-untrusted://new-tab-page/)."""
    import json

    urls = []
    for entry in driver.get_log("performance"):
        message = json.loads(entry["message"])["message"]
        if message.get("method") == "Network.requestWillBeSent":
            params = message["params"]
            own = (params.get("documentURL", ""), params["request"]["url"])
            if not any(u.startswith(BROWSER_OWN) for u in own):
                urls.append(params["request"]["url"])
    return urls


def console_errors(driver: Any) -> list[str]:
    """The console's messages of level SEVERE since the last call."""
    return [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def wait_for(predicate: Callable[[], Any], timeout_s: float, what: str) -> Any:
    """The first true value of ``predicate()``, polled every 0.2 s; AssertionError naming
    ``what`` after ``timeout_s`` s."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        v = predicate()
        if v:
            return v
        time.sleep(0.2)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
