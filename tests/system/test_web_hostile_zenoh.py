"""The web map against hostile sessions on a real router: an update it cannot read is shown
as such, and a rogue session's poison statuses stop neither watch nor its map."""

from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from tests.support.watch_fixtures import (
    TinyPublisher,
    ZenohTinyDaemon,
    free_port,
    read_line,
    zenoh_conf,
)

TOKEN = "hostile-test-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
APP_JS = Path(__file__).resolve().parents[2] / "service/pdcov/ground/web/app.js"


def strict(text: str | bytes):
    """json.loads that refuses NaN and the infinities, as the browser's JSON.parse does."""
    def refuse(name):
        raise ValueError(f"{name} is not JSON")
    return json.loads(text, parse_constant=refuse)


# The page's script run by node against a stand-in DOM and a stand-in Leaflet: what the
# operator sees when an update cannot be read.
NODE_HARNESS = r"""
const fs = require("fs");
const elements = {};
function stub(name) {
  const store = {};
  return new Proxy(function () {}, {
    get(t, k) {
      if (k in store) return store[k];
      if (k === Symbol.toPrimitive) return () => "";
      if (k === "dataset" || k === "style") return store[k] = {};
      if (k === "firstChild") return stub(name + ".child");
      return stub(name + "." + String(k));
    },
    set(t, k, v) { store[k] = v; return true; },
    apply() { return stub(name + "()"); },
    construct() { return stub("new " + name); },
  });
}
global.L = stub("L");  // Leaflet: every call answers a stand-in
global.document = {
  getElementById: (id) => elements[id] || (elements[id] = stub(id)),
  createElement: (tag) => stub(tag),
};
global.window = {innerWidth: 1200, innerHeight: 900, location: {href: "http://h/"},
                 addEventListener() {}};
global.history = {replaceState() {}};
let source = null;
global.EventSource = function () { source = this; };
global.EventSource.CLOSED = 2;
eval(fs.readFileSync(process.argv[2], "utf8"));
const error = document.getElementById("error");
const out = {};
source.onmessage({data: '{"version": 1, "mean_pd": Infinity}'});
out.bad = {hidden: error.hidden, text: String(error.textContent)};
source.onmessage({data: JSON.stringify({
  version: 2, fleet: {target: 0.8, thresholds: [0.8], proportion: {"0.8": 0.5}, mean_pd: 0.4,
                      merged: ["uav1"], cells_free: 10},
  grid: null, domain: null, domain_note: null, vehicles: [], origin: null, basemap: null})});
const coverage = document.getElementById("coverage");
out.good = {hidden: error.hidden, coverage: String(coverage.textContent)};
process.stdout.write(JSON.stringify(out));
"""


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")
def test_the_page_shows_an_update_it_cannot_read(tmp_path):
    harness = tmp_path / "harness.js"
    harness.write_text(NODE_HARNESS)
    run = subprocess.run(["node", str(harness), str(APP_JS)], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert out["bad"]["hidden"] is False
    assert "could not be read" in out["bad"]["text"], out
    assert out["good"] == {"hidden": True, "coverage": "50.0 %"}, out


def _poison_statuses(good: dict) -> list[bytes]:
    """The red team's statuses: each made `pdcov watch` exit (ValueError) or froze the map
    (Infinity); and one far over the status bound."""
    out = [json.dumps({**good, "proportion_at_or_above": {"abc": 0.5}}),
           json.dumps({**good, "thresholds": ["x"]}),
           json.dumps({**good, "mean_pd": "@@"}).replace('"@@"', "Infinity"),
           json.dumps({**good, "grid": {**good["grid"], "origin": {
               "lat_deg": "@@", "lon_deg": 0}}}).replace('"@@"', "NaN"),
           json.dumps({**good, "thresholds": [i / 6000 for i in range(5500)]})]
    return [s.encode() for s in out]


def test_a_rogue_sessions_poison_statuses_stop_neither_watch_nor_its_map(
        router, processes, daemons, tmp_path):
    zenoh = pytest.importorskip("zenoh")
    daemon = ZenohTinyDaemon(TinyPublisher("uav1"), router)
    daemons.append(daemon)
    daemon.publish_step(3)
    port = free_port()
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n")
    token_file.chmod(0o600)
    watch = subprocess.Popen(
        [sys.executable, "-m", "pdcov.cli", "watch", "--mode", "client", "--zenoh-connect",
         router, "--no-multicast-scouting", "--plain", "--web", f"127.0.0.1:{port}",
         "--web-token-file", str(token_file)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    processes.append(watch)
    line = read_line(watch, 60.0)
    assert re.search(rf"web map at http://127\.0\.0\.1:{port}/", line), line

    def state() -> dict:
        req = urllib.request.Request(f"http://127.0.0.1:{port}/state.json", headers=AUTH)
        with urllib.request.urlopen(req, timeout=10) as r:
            return strict(r.read())

    deadline = time.monotonic() + 30
    while not (state()["vehicles"] and state()["fleet"]["proportion"]):
        assert time.monotonic() < deadline, "the map never showed uav1"
        time.sleep(0.2)
    rogue = zenoh.open(zenoh_conf("client", connect=router))
    try:
        good = json.loads(daemon.pub.status())
        for _ in range(3):
            for payload in _poison_statuses(good):
                rogue.put("pdcov/uav1/status", payload)
                rogue.put("pdcov/rogue/status", payload)
            time.sleep(0.3)
        daemon.publish_step(2)
        time.sleep(1.5)
        assert watch.poll() is None, "pdcov watch exited"
        doc = state()  # strict JSON, and uav1's figures are its daemon's
    finally:
        rogue.close()
    (uav1,) = [v for v in doc["vehicles"] if v["id"] == "uav1"]
    expected = daemon.pub.grid.metrics([0.8]).proportion_at_or_above[0.8]
    assert uav1["proportion"]["0.8"] == pytest.approx(expected, abs=1e-12)
    assert all(isinstance(v["mean_pd"], float) for v in doc["vehicles"])
    watch.send_signal(signal.SIGTERM)
    out, _ = watch.communicate(timeout=60)
    assert watch.returncode == 0, out
    assert "not a usable status" in out and "Traceback" not in out
