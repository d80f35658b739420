"""The mission geometry over the bus, end to end on loopback: the real daemon (`pdcov serve`,
no autopilot needed: the mission queryable answers from the config) behind a Zenoh router in
this process, and `pdcov watch` without --config: the watcher asks for pdcov/uav1/mission,
its web map draws the domain and obstacles from it (state and, in headless chromium, the
drawn pixels), and its recording keeps the reply. Every process is stopped in teardown."""

from __future__ import annotations

import contextlib
import json
import re
import signal
import subprocess
import sys
import urllib.request

import numpy as np
import pytest

from pdcov.bus.mission import decode_mission
from tests.support.chromium import wait_for
from tests.support.serve_harness import (
    Subscriber,
    free_port,
    process,
    router,
    serve_args,
    serve_config,
)

BOUNDARY = [[-10.0, -10.0], [50.0, -10.0], [50.0, 40.0], [-10.0, 40.0]]
OBSTACLE = [[10.0, 10.0], [25.0, 10.0], [25.0, 22.0], [10.0, 22.0]]
MISSION = {
    "vehicle_id": "uav1",
    "origin": {"lat_deg": -35.363261, "lon_deg": 149.165230},  # ground altitude: from home
    "domain": {"polygon_enu_m": BOUNDARY, "obstacles_enu_m": [OBSTACLE], "cell_size_m": 1.0},
    "camera": {"width_px": 640, "height_px": 480,
               "K": [[480.0, 0.0, 319.5], [0.0, 480.0, 239.5], [0.0, 0.0, 1.0]],
               "frame_rate_hz": 5},
    "mount": {"type": "fixed", "roll_deg": 0, "pitch_deg": -90, "yaw_deg": 0},
    "detector": "illustrative",
    "thresholds": [0.5, 0.9],
}


def closed(ring):
    return [list(p) for p in ring] + [list(ring[0])]


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    """(zenoh port, the daemon's status, its mission reply) with `pdcov serve` running."""
    tmp = tmp_path_factory.mktemp("mission")
    zport = free_port()
    cfg = serve_config(MISSION, tmp / "m.yaml", zenoh_port=zport, state_dir=tmp / "state")
    r = router(zport)
    sub = None
    try:
        # A MAVLink endpoint nobody listens on: the daemon waits for its autopilot and
        # publishes and answers queries meanwhile.
        with process(serve_args(cfg, "--connect", f"tcp:127.0.0.1:{free_port()}"),
                     tmp / "serve.log"):
            sub = Subscriber(zport, "uav1")
            status = sub.wait(lambda s: True, 60, "the daemon's first status")
            reply = None
            for r_ in sub.session.get(sub.keys.mission, timeout=5.0):
                if r_.ok is not None:
                    reply = r_.ok.payload.to_bytes()
            assert reply is not None, (tmp / "serve.log").read_text()
            yield zport, status, reply
    finally:
        if sub is not None:
            sub.close()
        r.close()


@contextlib.contextmanager
def watcher(zport: int, *extra: str):
    """`pdcov watch` (client of the router, no --config) with its web map; yields (process,
    the map's URL as printed, its access token included); SIGTERM then kill in teardown."""
    port = free_port()
    p = subprocess.Popen(
        [sys.executable, "-m", "pdcov.cli", "watch", "--mode", "client", "--zenoh-connect",
         f"tcp/127.0.0.1:{zport}", "--no-multicast-scouting", "--plain",
         "--web", f"127.0.0.1:{port}", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        line = p.stdout.readline()
        m = re.search(rf"web map at (http://127\.0\.0\.1:{port}/\?token=\S+)$", line.strip())
        assert m, line
        yield p, m.group(1)
    finally:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)


def map_state(url: str) -> dict:
    """/state.json of the map at ``url`` (…/?token=T)."""
    with urllib.request.urlopen(url.replace("/?token=", "/state.json?token="),
                                timeout=5) as r:
        return json.load(r)


def test_the_daemon_answers_its_mission(daemon):
    _, status, reply = daemon
    m = decode_mission(reply, "pdcov/uav1/mission", "uav1")
    assert m.grid_hash == status["grid"]["hash"]
    assert m.boundary_enu_m == tuple(map(tuple, closed(BOUNDARY)))
    assert m.obstacles_enu_m == (tuple(map(tuple, closed(OBSTACLE))),)
    g = status["grid"]
    assert (m.geometry.x0_m, m.geometry.y0_m, m.geometry.n_rows, m.geometry.n_cols) == \
        (g["x0_m"], g["y0_m"], g["n_rows"], g["n_cols"]) == (-10.0, -10.0, 50, 60)
    assert m.ground_alt_msl_m is None  # no autopilot, no home: not known yet
    assert m.thresholds == (0.5, 0.9) and m.target_pd == 0.9


def test_watcher_without_config_draws_the_vehicles_domain(daemon, tmp_path):
    zport, status, reply = daemon
    with watcher(zport, "--record", str(tmp_path / "rec")) as (p, url):
        state = wait_for(lambda: (s := map_state(url))["domain"] and s, 30,
                         "the domain in the map state")
        assert state["domain"]["source"] == "vehicle uav1"
        assert state["domain"]["grid_hash"] == status["grid"]["hash"]
        assert state["grid"] is not None and state["domain_note"] is None
        assert state["domain"]["boundary"] == closed(BOUNDARY)
        assert state["domain"]["obstacles"] == [closed(OBSTACLE)]
        p.send_signal(signal.SIGTERM)
        p.communicate(timeout=30)
        assert p.returncode == 0
    recorded = tmp_path / "rec" / "uav1" / "mission-1.json"
    assert recorded.read_bytes() == reply
    assert not (tmp_path / "rec" / "uav1" / "mission-2.json").exists()  # asked once


def test_web_map_in_chromium_outlines_the_domain_without_config(daemon, browser, tmp_path):
    zport, _, _ = daemon
    with watcher(zport) as (_, url):
        browser.get(url)
        wait_for(lambda: browser.execute_script(
            "return document.getElementById('map').dataset.domainSource"), 30,
            "the domain drawn on the map")
        source, legend = browser.execute_script("""
            return [document.getElementById('map').dataset.domainSource,
                    document.getElementById('domain-source').textContent];""")
        assert source == legend == "vehicle uav1"
        # Drawn from the vehicle's mission reply: its WGS84 rings, on the map as polygons
        # (the obstacle filled, the boundary outlined).
        state = map_state(url)
        shapes = browser.execute_script("""
            return window.pdcov.layers.domain.getLayers().map((p) => [
              p.options.fill, p.getLatLngs()[0].map((q) => [q.lat, q.lng])]);""")
        assert [fill for fill, _ in shapes] == [True, False]
        for (_, drawn), ring in zip(shapes, [*state["domain"]["obstacles_lat_lon"],
                                             state["domain"]["boundary_lat_lon"]],
                                    strict=True):
            # Leaflet drops the repeated first position.
            np.testing.assert_allclose(drawn, ring[:-1], atol=1e-9)
        browser.save_screenshot(str(tmp_path / "web-map-mission.png"))
        assert (tmp_path / "web-map-mission.png").stat().st_size > 10_000
