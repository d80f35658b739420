"""The web map under hostile input and many clients (issue 23): nothing non-finite reaches
the page's data, the state is built once per change for every client, the page shows an
update it cannot read instead of freezing, and a rogue Zenoh session's poison statuses
stop neither `pdcov watch` nor its map (real router, real watch process, real HTTP)."""

from __future__ import annotations

import asyncio
import json
import math
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from watch_fixtures import TinyPublisher, ZenohTinyDaemon, free_port, read_line, zenoh_conf

from pdcov.ground.web import WebMap, state_json
from pdcov.ground.web_auth import WebAccess, served_names

TOKEN = "hostile-test-token-0123456789abcdef"
ACCESS = WebAccess(TOKEN, served_names("127.0.0.1", "groundstation", []))
AUTH = {"Authorization": f"Bearer {TOKEN}"}
APP_JS = Path(__file__).resolve().parents[1] / "service/pdcov/ground/web/app.js"


def strict(text: str | bytes):
    """json.loads that refuses NaN and the infinities, as the browser's JSON.parse does."""
    def refuse(name):
        raise ValueError(f"{name} is not JSON")
    return json.loads(text, parse_constant=refuse)


def test_state_json_makes_non_finite_numbers_null():
    state = {"version": 3, "fleet": {"mean_pd": math.inf, "proportion": {"0.8": math.nan}},
             "vehicles": [{"age_s": -math.inf, "track": [[1.0, math.nan]]}]}
    doc = strict(state_json(state))
    assert doc["fleet"] == {"mean_pd": None, "proportion": {"0.8": None}}
    assert doc["vehicles"] == [{"age_s": None, "track": [[1.0, None]]}]
    with pytest.raises(ValueError, match="Infinity"):
        strict(json.dumps(state))  # what the page used to receive


async def _first_event(resp) -> dict:
    buf = b""
    while not buf.endswith(b"\n\n"):
        buf += await resp.content.readany()
    (line,) = [ln for ln in buf.split(b"\n") if ln.startswith(b"data: ")][-1:]
    return strict(line[6:])


async def _serve(state, version, **kw) -> WebMap:
    web = WebMap("127.0.0.1", 0, state, version, ACCESS, None, **kw)
    await web.start()
    return web


def test_non_finite_state_reaches_both_endpoints_as_strict_json():
    async def run():
        import aiohttp

        web = await _serve(lambda: {"version": 1, "mean_pd": math.inf}, lambda: 1,
                           period_s=0.02)
        try:
            async with aiohttp.ClientSession(headers=AUTH) as http:
                base = f"http://127.0.0.1:{web.port}"
                async with http.get(f"{base}/state.json") as r:
                    assert r.status == 200 and r.content_type == "application/json"
                    assert strict(await r.read())["mean_pd"] is None
                async with http.get(f"{base}/events") as r:
                    assert (await _first_event(r))["mean_pd"] is None
        finally:
            await web.stop()
    asyncio.run(run())


def test_the_state_is_built_once_per_version_for_every_client():
    """N live-event clients and M /state.json readers: one build per version change, not
    one per client (the red team's 200 clients pinned a core)."""
    n_clients, n_changes = 40, 5
    version = [0]
    builds = []

    def state():
        builds.append(version[0])
        return {"version": version[0]}

    async def run():
        import aiohttp

        web = await _serve(state, lambda: version[0], period_s=0.02, refresh_s=3600.0)
        base = f"http://127.0.0.1:{web.port}"
        try:
            async with aiohttp.ClientSession(headers=AUTH) as http:
                streams = [await http.get(f"{base}/events") for _ in range(n_clients)]
                for r in streams:
                    assert (await _first_event(r))["version"] == 0
                for v in range(1, n_changes + 1):
                    version[0] = v
                    got = await asyncio.wait_for(
                        asyncio.gather(*(_first_event(r) for r in streams)), 10)
                    assert [g["version"] for g in got] == [v] * n_clients
                    for _ in range(10):
                        async with http.get(f"{base}/state.json") as r:
                            assert strict(await r.read())["version"] == v
                for r in streams:
                    r.close()
        finally:
            await web.stop()
    asyncio.run(run())
    assert builds == list(range(n_changes + 1)), builds


def test_a_state_that_cannot_be_built_keeps_the_map_and_says_so(caplog):
    """A defect in building one update must not end the stream or answer 500: the page
    keeps the last state, with the error to show (app.js), and the next version is built
    again."""
    version = [0]

    def state():
        if version[0] == 1:
            raise KeyError("fleet")
        return {"version": version[0], "fleet": {"target": 0.8}}

    async def run():
        import aiohttp

        web = await _serve(state, lambda: version[0], period_s=0.02, refresh_s=3600.0)
        base = f"http://127.0.0.1:{web.port}"
        try:
            async with aiohttp.ClientSession(headers=AUTH) as http:
                stream = await http.get(f"{base}/events")
                assert (await _first_event(stream))["version"] == 0
                version[0] = 1
                bad = await asyncio.wait_for(_first_event(stream), 10)
                assert bad["version"] == 1 and bad["fleet"] == {"target": 0.8}
                assert bad["build_error"] == "KeyError: 'fleet'"
                async with http.get(f"{base}/state.json") as r:
                    assert r.status == 200 and strict(await r.read())["build_error"]
                version[0] = 2
                good = await asyncio.wait_for(_first_event(stream), 10)
                assert good == {"version": 2, "fleet": {"target": 0.8}}
                stream.close()
        finally:
            await web.stop()
    asyncio.run(run())
    assert sum("could not be built" in r.getMessage() for r in caplog.records) == 1


def test_the_state_is_rebuilt_after_refresh_s_for_the_ages():
    builds = []

    async def run():
        web = await _serve(lambda: builds.append(1) or {"n": len(builds)}, lambda: 7,
                           refresh_s=0.05)
        try:
            first = web.current()
            assert web.current() is first and len(builds) == 1
            await asyncio.sleep(0.06)
            assert strict(web.current().data) == {"n": 2}
        finally:
            await web.stop()
    asyncio.run(run())


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


@pytest.mark.e2e
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


# -- end to end: a rogue session on the default bus -----------------------------------

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


@pytest.mark.e2e
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
