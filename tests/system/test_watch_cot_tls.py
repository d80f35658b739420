"""`pdcov watch --cot tls://` as a process, fed over real Zenoh on loopback, sending to a TLS
server on 127.0.0.1 that requires a client certificate signed by its CA (a TAK server's
8089): the events arrive and parse as CoT; a watcher whose certificate another CA signed is
refused, says so once and keeps running while it retries."""

from __future__ import annotations

import time

import pytest

from pdcov.report.cot_events import AIRCRAFT_TYPE
from tests.support.tak_tls_server import TakTlsServer
from tests.support.tls_certs import Authority
from tests.support.watch_fixtures import (
    TinyPublisher,
    ZenohTinyDaemon,
    start_watcher,
    stop_watcher,
)

zenoh = pytest.importorskip("zenoh")
pytest.importorskip("pytak")


def test_watch_sends_cot_over_mutual_tls_and_a_stranger_is_refused(router, processes,
                                                                   daemons, tmp_path):
    tak, other = Authority(tmp_path / "tak", "TAK CA"), Authority(tmp_path / "other", "X")
    ours, stranger = tak.leaf("pdcov-ground"), other.leaf("pdcov-ground")
    server = TakTlsServer(tak.leaf("tak-server"), tak.ca)
    try:
        d = ZenohTinyDaemon(TinyPublisher("uav1"), router)
        daemons.append(d)
        url = f"tls://127.0.0.1:{server.port}"
        good = start_watcher(processes, router, "--cot", url, "--cot-cert", ours.cert,
                             "--cot-key", ours.key, "--cot-ca", tak.ca)
        bad = start_watcher(processes, router, "--cot", url, "--cot-cert", stranger.cert,
                            "--cot-key", stranger.key, "--cot-ca", tak.ca)
        end = time.monotonic() + 30.0
        while time.monotonic() < end and (len(server.refused) < 2 or not server.events):
            d.publish_step()  # a new status position: an aircraft event
            time.sleep(0.2)
        assert len(server.refused) >= 2, server.refused  # retried after 5 s
        assert good.poll() is None and bad.poll() is None  # both still watching
        air = [e for e in server.events if e.get("type") == AIRCRAFT_TYPE]
        assert air and air[0].get("uid") == "pdcov-uav1"
        o = d.pub.mission.origin()
        point = air[-1].find("point")
        assert float(point.get("lat")) == pytest.approx(o.lat_deg, abs=1e-3)
        assert float(point.get("lon")) == pytest.approx(o.lon_deg, abs=1e-6)
        assert set(server.clients) == {"pdcov-ground"}
        out_bad, out_good = stop_watcher(bad), stop_watcher(good)
        logged = [line for line in out_bad.splitlines() if line.startswith(f"--cot {url}")]
        shown = [line for line in out_bad.splitlines() if f"! --cot {url}" in line]
        assert len(logged) == len(shown) == 1, out_bad  # once, though retried
        assert "refused the client certificate --cot-cert" in logged[0], out_bad
        assert str(stranger.cert) in logged[0], out_bad
        assert f"--cot {url}" not in out_good, out_good
    finally:
        server.close()
