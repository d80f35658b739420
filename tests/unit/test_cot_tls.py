"""--cot tls://: the identity checked before the watcher starts (one ConfigError naming the
option and the file), and the feed against a TLS server on 127.0.0.1 that requires a
client certificate: events delivered, a certificate of another CA refused and said once
while the feed keeps trying, a server down then up."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
import ssl
import time
from pathlib import Path

import pytest

from pdcov.errors import ConfigError
from pdcov.ground.cot import CotSchedule
from pdcov.ground.cot_feed import CotFeed, parse_cot_url
from pdcov.ground.cot_tls import CotTls, CotTlsFiles, cot_tls_of
from pdcov.ground.feed import VehicleFeed
from pdcov.report.cot_events import AIRCRAFT_TYPE
from tests.support.harness import free_port
from tests.support.tak_tls_server import TakTlsServer
from tests.support.tls_certs import Authority

URL = "tls://127.0.0.1:8089"


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    """The TAK server's CA (server and our client certificate) and someone else's."""
    folder = tmp_path_factory.mktemp("pki")
    tak, other = Authority(folder / "tak", "TAK CA"), Authority(folder / "other", "other CA")
    return {"ca": tak, "other": other, "server": tak.leaf("tak-server"),
            "client": tak.leaf("pdcov-ground"), "stranger": other.leaf("pdcov-ground")}


def password_file(folder: Path, text: str, mode: int = 0o600) -> Path:
    f = folder / "password"
    f.write_text(text + "\n")
    f.chmod(mode)
    return f


def checked(files: CotTlsFiles, url: str = URL) -> CotTls | None:
    tls = cot_tls_of(url, files, time.time())
    if tls is not None:
        tls.close()
    return tls


def test_a_pem_identity_becomes_pytak_settings_with_the_key_encrypted_in_memory(pki):
    c = pki["client"]
    tls = cot_tls_of(URL, CotTlsFiles(c.cert, c.key, None, pki["ca"].ca), time.time())
    try:
        assert tls is not None and tls.subject == "CN=pdcov-ground"
        settings = tls.pytak_settings()
        pem = Path(settings["PYTAK_TLS_CLIENT_CERT"]).read_bytes()
        assert pem.startswith(b"-----BEGIN CERTIFICATE-----")
        assert b"ENCRYPTED PRIVATE KEY" in pem and b"-----BEGIN PRIVATE KEY" not in pem
        assert settings["PYTAK_TLS_CLIENT_CAFILE"] == str(pki["ca"].ca)
        assert "PYTAK_TLS_DONT_VERIFY" not in settings
        assert "PYTAK_TLS_SERVER_EXPECTED_HOSTNAME" not in settings
        assert tls.identity_password not in repr(tls)
    finally:
        tls.close()
    assert cot_tls_of("tcp://h:8087", CotTlsFiles(), 0.0) is None
    assert cot_tls_of(None, CotTlsFiles(), 0.0) is None


def test_an_encrypted_key_and_a_p12_open_with_the_password_file(pki, tmp_path):
    pw = "100% tak"  # a % that pytak's ConfigParser would take for interpolation
    ca = Authority(tmp_path / "ca")
    leaf = ca.leaf("enc", key_password=pw.encode())
    f = password_file(tmp_path, pw)
    assert checked(CotTlsFiles(leaf.cert, leaf.key, f, ca.ca)) is not None
    p12 = ca.p12(ca.leaf("p12"), pw.encode())
    p12.chmod(0o400)  # read-only is enough (pytak's own .p12 loader opens it "r+")
    assert checked(CotTlsFiles(p12, None, f, ca.ca, "tak.example")).server_name \
        == "tak.example"
    combined = tmp_path / "combined.pem"  # key and certificate in one file
    combined.write_bytes(pki["client"].cert.read_bytes() + pki["client"].key.read_bytes())
    assert checked(CotTlsFiles(combined, None, None, pki["ca"].ca)) is not None


def refusals(pki, tmp: Path) -> list[tuple[CotTlsFiles | tuple[str, CotTlsFiles], str]]:
    c, ca = pki["client"], pki["ca"].ca
    pw = password_file(tmp, "secret")
    enc = pki["ca"].leaf("enc", key_password=b"secret")
    expired = pki["ca"].leaf("old", expired=True)
    p12 = pki["ca"].p12(c, b"secret")
    junk = tmp / "junk.pem"
    junk.write_text("not a certificate")
    loose = tmp / "loose"
    loose.mkdir()
    return [
        (CotTlsFiles(tmp / "missing.pem", c.key, None, ca),
         r"--cot-cert .*missing\.pem: cannot read it \(No such file"),
        (CotTlsFiles(c.cert, c.key, None, tmp / "none.pem"), r"--cot-ca .*none\.pem: cannot"),
        (CotTlsFiles(c.cert, c.key, None, junk), r"--cot-ca .*junk\.pem: no PEM certificate"),
        (CotTlsFiles(c.cert, pki["stranger"].key, None, ca),
         r"--cot-key .*: not the key of --cot-cert .*pdcov-ground\.pem \(CN=pdcov-ground\)"),
        (CotTlsFiles(expired.cert, expired.key, None, ca),
         r"--cot-cert .*old\.pem: CN=old expired on 20"),
        (CotTlsFiles(enc.cert, enc.key, None, ca),
         r"--cot-key .*enc-key\.pem: encrypted: give its password with "
         r"--cot-key-password-file"),
        (CotTlsFiles(enc.cert, enc.key, password_file(loose, "wrong"), ca),
         r"--cot-key .*enc-key\.pem: cannot be read with the password .*wrong password"),
        (CotTlsFiles(c.cert, c.key, pw, ca), r"--cot-key .*: not encrypted: drop"),
        (CotTlsFiles(c.cert, None, None, ca), r"--cot-cert .*: no PEM private key in it "
                                              r"\(give --cot-key\)"),
        (CotTlsFiles(p12, None, None, ca), r"--cot-cert .*\.p12: neither PEM nor a PKCS#12 "
                                           r"file without a password"),
        (CotTlsFiles(p12, None, password_file(loose, "nope"), ca),
         r"\.p12: neither PEM nor a PKCS#12 file that --cot-key-password-file opens"),
        (CotTlsFiles(p12, c.key, pw, ca), r"--cot-key .*: not with a PKCS#12 --cot-cert"),
        (CotTlsFiles(enc.cert, enc.key, password_file(tmp / "..", "secret", 0o644), ca),
         r"--cot-key-password-file .*: permissions 0644 are too open"),
        (CotTlsFiles(c.cert, c.key), r"--cot tls://.*: needs --cot-cert .* and --cot-ca"),
        (("tcp://h:8087", CotTlsFiles(c.cert, c.key, None, ca)),
         r"--cot-cert, --cot-key, --cot-ca: only with --cot tls://HOST:PORT .*not --cot tcp"),
        ((None, CotTlsFiles(ca=ca)), r"--cot-ca: only with --cot tls://.*without --cot"),
    ]


def test_bad_identities_are_refused_naming_the_option_and_the_file(pki, tmp_path):
    for given, message in refusals(pki, tmp_path):
        url, files = given if isinstance(given, tuple) else (URL, given)
        with pytest.raises(ConfigError, match=message):
            checked(files, url)
    assert parse_cot_url("tls://tak.local:8089") == "tls://tak.local:8089"


def feed_of(url: str, tls: CotTls | None, **kw) -> tuple[CotFeed, VehicleFeed]:
    f = VehicleFeed("uav1")
    f.status = {"pose": {"lat_deg": 46.5, "lon_deg": 7.25, "alt_msl_m": 620.0,
                         "heading_deg": 90.0, "t_s": 1.0}}
    return CotFeed(url, CotSchedule(aircraft_period_s=0.05), lambda: [f], tls=tls,
                   period_s=0.05, **kw), f


async def run_until(feed: CotFeed, vehicle: VehicleFeed, done, timeout_s: float) -> None:
    """Run ``feed`` (the pose moving every tick, so that events keep coming) until
    ``done()``."""
    stop = asyncio.Event()
    task = asyncio.create_task(feed.run(stop))
    try:
        end = time.monotonic() + timeout_s
        while not done():
            assert time.monotonic() < end, "not done in time"
            assert not task.done(), task
            vehicle.status["pose"] = {**vehicle.status["pose"],
                                      "t_s": vehicle.status["pose"]["t_s"] + 1.0}
            await asyncio.sleep(0.05)
    finally:
        stop.set()
        await task


def identity(pki, leaf: str = "client", **kw) -> CotTls:
    c = pki[leaf]
    tls = cot_tls_of(URL, CotTlsFiles(c.cert, c.key, None, pki["ca"].ca, **kw), time.time())
    assert tls is not None
    return tls


def test_events_reach_a_server_that_requires_a_client_certificate(pki):
    server = TakTlsServer(pki["server"], pki["ca"].ca)
    try:
        feed, vehicle = feed_of(f"tls://127.0.0.1:{server.port}", identity(pki))
        asyncio.run(run_until(feed, vehicle, lambda: len(server.events) >= 3, 10.0))
        assert server.clients[0] == "pdcov-ground" and not server.refused
        e = server.events[0]
        assert (e.get("uid"), e.get("type")) == ("pdcov-uav1", AIRCRAFT_TYPE)
        assert float(e.find("point").get("lat")) == pytest.approx(46.5, abs=1e-6)
        assert feed.failures == 0
        # and a client without a certificate is refused (the server is what it says)
        with socket.create_connection(("127.0.0.1", server.port)) as raw, \
                ssl.create_default_context(cafile=pki["ca"].ca).wrap_socket(
                    raw, server_hostname="127.0.0.1") as s:
            with contextlib.suppress(ssl.SSLError, OSError):
                s.sendall(b"<event/>")
                assert s.recv(1) == b""  # refused: nothing but the end
        server.wait_for(lambda s: len(s.refused) == 1, 5.0)
        assert server.refused == ["PEER_DID_NOT_RETURN_A_CERTIFICATE"]
        assert len(server.events) >= 3 and server.clients == ["pdcov-ground"]
    finally:
        server.close()


def test_a_refused_certificate_is_said_once_and_retried(pki, caplog):
    server = TakTlsServer(pki["server"], pki["ca"].ca)
    other = pki["other"].leaf("pdcov-ground")
    tls = cot_tls_of(URL, CotTlsFiles(other.cert, other.key, None, pki["ca"].ca),
                     time.time())
    try:
        feed, vehicle = feed_of(f"tls://127.0.0.1:{server.port}", tls, retry_s=0.1,
                                settle_s=1.0)
        with caplog.at_level(logging.WARNING, "pdcov.watch"):
            asyncio.run(run_until(feed, vehicle, lambda: len(server.refused) >= 4, 10.0))
        lines = [r.getMessage() for r in caplog.records]
        assert len(lines) == 1, lines
        # by its alert, or (the alert lost in the reset of a connection we had written to,
        # as with this server) by ending the connection right after the handshake
        assert "refused the client certificate --cot-cert" in lines[0], lines[0]
        assert "other/pdcov-ground.pem (CN=pdcov-ground)" in lines[0]
        assert not server.events and feed.failures >= 3 and "refused" in feed.warning
        assert not os.path.exists(tls.identity_path)  # closed with the feed
    finally:
        server.close()


def test_a_server_another_ca_signed_is_not_trusted(pki, caplog):
    impostor = TakTlsServer(pki["other"].leaf("tak-server"), pki["ca"].ca)
    try:
        feed, vehicle = feed_of(f"tls://127.0.0.1:{impostor.port}", identity(pki),
                                retry_s=0.1)
        with caplog.at_level(logging.WARNING, "pdcov.watch"):
            asyncio.run(run_until(feed, vehicle, lambda: feed.failures >= 2, 10.0))
        assert "the server's certificate does not verify against --cot-ca" in feed.warning
        assert not impostor.events and len(caplog.records) == 1
    finally:
        impostor.close()


def test_a_certificate_for_another_name_needs_cot_server_name(pki, tmp_path):
    ca = pki["ca"]
    server = TakTlsServer(pki["server"], ca.ca)  # its certificate: localhost, 127.0.0.1
    try:
        url = f"tls://127.0.0.1:{server.port}"
        feed, vehicle = feed_of(url, identity(pki, server_name="tak.example"), retry_s=0.1)
        asyncio.run(run_until(feed, vehicle, lambda: feed.failures >= 1, 10.0))
        assert "--cot-server-name" in feed.warning and "tak.example" in feed.warning
        feed, vehicle = feed_of(url, identity(pki, server_name="localhost"))
        asyncio.run(run_until(feed, vehicle, lambda: len(server.events) >= 1, 10.0))
    finally:
        server.close()


def test_a_server_down_is_said_once_then_reached(pki, caplog):
    port = free_port()
    feed, vehicle = feed_of(f"tls://127.0.0.1:{port}", identity(pki), retry_s=0.1,
                            settle_s=0.2)
    servers: list[TakTlsServer] = []

    def up() -> bool:
        if feed.failures >= 3 and not servers:
            servers.append(TakTlsServer(pki["server"], pki["ca"].ca, port))
        return bool(servers) and len(servers[0].events) >= 2 and feed.warning is None

    try:
        with caplog.at_level(logging.WARNING, "pdcov.watch"):
            asyncio.run(run_until(feed, vehicle, up, 15.0))
        lines = [r.getMessage() for r in caplog.records]
        assert len(lines) == 2 and "connecting failed" in lines[0], lines
        assert "sending again" in lines[1]
    finally:
        for s in servers:
            s.close()
