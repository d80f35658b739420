"""`pdcov watch --cot` against a real TAK server: taky (PyPI, a Python TAK server; the
`test` extra) as its own process on 127.0.0.1, with TLS and client certificates its CA
signed as a SAR team deploys it, and with plain TCP. The watcher, fed over real Zenoh on
loopback, sends its aircraft and its pins; a second TAK client connected as ATAK is (its
own certificate, its position announced) receives them as taky relays them, and they
parse as CoT with the uid, type, position and details pdcov sent. Clients whose
certificate another CA signed are refused: a plain TLS socket, and a watcher that says
so and keeps running."""

from __future__ import annotations

import importlib.util
import time
import xml.etree.ElementTree as ET

import pytest

from pdcov.bus.detections import encode_detections
from pdcov.bus.sources import SourcedPublisher
from pdcov.core.geodesy import DEG_DECIMALS
from pdcov.report.cot_events import AIRCRAFT_TYPE, CANDIDATE_TYPE, CE90_PER_SIGMA
from tests.support.exports_fixtures import detections_doc
from tests.support.taky_server import TakClient, TakyServer, client_context
from tests.support.tls_certs import Authority
from tests.support.watch_fixtures import (
    TinyPublisher,
    ZenohTinyDaemon,
    start_watcher,
    stop_watcher,
)

for needed in ("zenoh", "pytak"):  # the bus, and the watcher's CoT client
    pytest.importorskip(needed)
if importlib.util.find_spec("taky") is None:
    pytest.skip("taky (the TAK server these tests run: pip install taky, in the `test` "
                "extra) is not installed", allow_module_level=True)

REFUSED = "CERTIFICATE_VERIFY_FAILED"
"""taky's log line when it refuses a client's certificate (OpenSSL's reason)."""
DEG = 10.0 ** -min(DEG_DECIMALS, 6)  # taky writes a point's lat and lon with 6 decimals


def feed_until(d: ZenohTinyDaemon, atak: TakClient, done, timeout_s: float = 40.0) -> list:
    """Publish a status position (an aircraft event) and pins 3 and 4 (their events) every
    0.2 s until ``done(events)`` for what ``atak`` received; the status latitudes sent."""
    detections = SourcedPublisher(d.session.declare_publisher(d.keys.detections))
    payload = encode_detections(detections_doc("uav1"))
    lats: list[float] = []
    try:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and not done(atak.snapshot()):
            d.publish_step()
            lats.append(d.pub.mission.origin().lat_deg + 1e-5 * d.pub.grid.frames)
            detections.put(payload)  # dropped until the watcher follows the daemon
            time.sleep(0.2)
    finally:
        detections.undeclare()
    return lats


def of_type(events: list[ET.Element], cot_type: str) -> list[ET.Element]:
    return [e for e in events if e.get("type") == cot_type]


def pins_in(events: list[ET.Element]) -> set[str]:
    return {e.get("uid", "") for e in of_type(events, CANDIDATE_TYPE)}


def relayed_all(events: list[ET.Element]) -> bool:
    return bool(of_type(events, AIRCRAFT_TYPE)) and \
        pins_in(events) >= {"uav1.3fa2c1.3", "uav1.3fa2c1.4"}


def check_relayed(events: list[ET.Element], d: ZenohTinyDaemon, lats: list[float]) -> None:
    """The aircraft at a status position pdcov was given, the pins as pdcov sent them."""
    air = of_type(events, AIRCRAFT_TYPE)
    assert {e.get("uid") for e in air} == {"pdcov-uav1"}
    o = d.pub.mission.origin()
    for e in air:
        p = e.find("point")
        assert p is not None
        assert min(abs(float(p.get("lat")) - lat) for lat in lats) <= DEG, ET.tostring(e)
        assert float(p.get("lon")) == pytest.approx(o.lon_deg, abs=DEG)
        assert e.find("detail/contact").get("callsign") == "pdcov uav1"
    pins = {c["uid"]: c for c in detections_doc("uav1")["candidates"]}
    for e in of_type(events, CANDIDATE_TYPE):
        c = pins[e.get("uid")]
        p = e.find("point")
        assert float(p.get("lat")) == pytest.approx(c["lat_deg"], abs=DEG)
        assert float(p.get("lon")) == pytest.approx(c["lon_deg"], abs=DEG)
        assert float(p.get("ce")) == pytest.approx(CE90_PER_SIGMA * c["sigma_m"], abs=0.05)
        assert e.find("detail/link").get("uid") == "pdcov-uav1"
        callsign = e.find("detail/contact").get("callsign")
        assert callsign == f"person {c['p_person']:.2f} {c['uid']}"
        assert f"detected {c['hits']} of {c['looks']} looks" in e.find("detail/remarks").text


def check_log(log: str) -> None:
    """taky parsed every event it got (it logs and drops what it cannot read)."""
    for fault in ("Unable to parse Event", "Unhandled exception", "XML Syntax Error"):
        assert fault not in log, log[-4000:]


def test_taky_relays_the_watchers_cot_over_mutual_tls(router, processes, daemons, tmp_path):
    tak, other = Authority(tmp_path / "tak", "TAK CA"), Authority(tmp_path / "other", "X")
    ours, stranger = tak.leaf("pdcov-ground"), other.leaf("pdcov-ground")
    server = TakyServer(tmp_path / "taky", tak.leaf("tak-server"), tak.ca)
    atak = None
    try:
        d = ZenohTinyDaemon(TinyPublisher("uav1"), router)
        daemons.append(d)
        atak = TakClient(server.port, "ANDROID-sar1", client_context(tak.leaf("sar1"), tak.ca))
        url = f"tls://127.0.0.1:{server.port}"
        # The name in taky's certificate, as when the URL dials an address
        good = start_watcher(processes, router, "--cot", url, "--cot-cert", ours.cert,
                             "--cot-key", ours.key, "--cot-ca", tak.ca,
                             "--cot-server-name", "localhost")
        bad = start_watcher(processes, router, "--cot", url, "--cot-cert", stranger.cert,
                            "--cot-key", stranger.key, "--cot-ca", tak.ca)
        lats = feed_until(d, atak, relayed_all)
        events = atak.snapshot()
        assert relayed_all(events), [ET.tostring(e) for e in events]
        check_relayed(events, d, lats)
        # The stranger watcher refused, and refused again when it retried 5 s later.
        server.wait_log(REFUSED, 2, 30.0)
        # A TAK client whose certificate another CA signed gets nothing.
        intruder = TakClient(server.port, "ANDROID-x", client_context(
            other.leaf("x"), tak.ca))
        assert intruder.wait_closed(10.0) is not None
        assert intruder.snapshot() == []
        intruder.close()
        assert good.poll() is None and bad.poll() is None  # both still watching
        out_bad, out_good = stop_watcher(bad), stop_watcher(good)
        logged = [line for line in out_bad.splitlines() if line.startswith(f"--cot {url}")]
        assert len(logged) == 1, out_bad  # said once, though retried
        assert f"the client certificate --cot-cert {stranger.cert}" in logged[0], out_bad
        assert f"--cot {url}" not in out_good, out_good  # ATAK's relayed SA read, dropped
    finally:
        if atak is not None:
            atak.close()
        log = server.close()
    check_log(log)
    assert log.count(REFUSED) >= 3  # the watcher twice, the TAK client


def test_taky_relays_the_watchers_cot_over_plain_tcp(router, processes, daemons, tmp_path):
    server = TakyServer(tmp_path / "taky")
    atak = None
    try:
        d = ZenohTinyDaemon(TinyPublisher("uav1"), router)
        daemons.append(d)
        atak = TakClient(server.port, "ANDROID-sar1")
        url = f"tcp://127.0.0.1:{server.port}"
        good = start_watcher(processes, router, "--cot", url)
        lats = feed_until(d, atak, relayed_all)
        events = atak.snapshot()
        assert relayed_all(events), [ET.tostring(e) for e in events]
        check_relayed(events, d, lats)
        # taky keeps each uid's last event until it is stale and hands them to a client
        # that connects later (an ATAK joining the search): the pins, stale 5 min on.
        late = TakClient(server.port, "ANDROID-sar2")
        end = time.monotonic() + 10.0
        while time.monotonic() < end and len(pins_in(late.snapshot())) < 2:
            time.sleep(0.1)
        assert pins_in(late.snapshot()) == {"uav1.3fa2c1.3", "uav1.3fa2c1.4"}
        late.close()
        assert f"--cot {url}" not in stop_watcher(good)
    finally:
        if atak is not None:
            atak.close()
        log = server.close()
    check_log(log)
