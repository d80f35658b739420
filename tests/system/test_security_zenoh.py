"""Zenoh over TLS and mutual TLS, and access control, with real sessions on loopback and
certificates made here (tls_certs): the example configs in systemd/zenoh/ let a vehicle
publish only its own keys and the ground station read pdcov/** but publish nothing; a
peer without an accepted certificate gets nothing; `pdcov serve` and `pdcov watch` pass
their bus TLS settings through to Zenoh (docs/reliability.md "Security"); only the
authorised ground station (common name "ops") reaches a daemon's pdcov/<id>/retask."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from pdcov.bus.retask import decode_retask_reply
from pdcov.bus.session import BusConfig, open_session
from pdcov.core.mission import MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT, MissionItem
from pdcov.errors import ConfigError
from tests.support.retask_keys import signed, write_pub
from tests.support.serve_harness import ROOT, free_port, process, serve_args, stop
from tests.support.tls_certs import Authority

EXAMPLES = ROOT / "systemd" / "zenoh"
MISSION = {
    "vehicle_id": "uav1",
    "origin": {"lat_deg": 47.397742, "lon_deg": 8.545594, "ground_alt_msl_m": 488.0},
    "domain": {"polygon_enu_m": [[0, 0], [20, 0], [20, 20], [0, 20]], "cell_size_m": 1.0},
    "camera": {"width_px": 640, "height_px": 480,
               "K": [[480.0, 0.0, 319.5], [0.0, 480.0, 239.5], [0.0, 0.0, 1.0]],
               "distortion_model": "plumb_bob",
               "distortion_coeffs": [0.0, 0.0, 0.0, 0.0, 0.0], "frame_rate_hz": 5},
    "mount": {"type": "fixed", "roll_deg": 0, "pitch_deg": -90, "yaw_deg": 0},
    "detector": "illustrative",
}


def example(name: str, certs: Path, out: Path, port: int) -> Path:
    """systemd/zenoh/NAME with the certificate folder and the router's endpoint of this
    test (the file is otherwise used as shipped)."""
    text = (EXAMPLES / name).read_text()
    text = text.replace("/etc/pdcov/tls/", f"{certs}/")
    text = text.replace("tls/0.0.0.0:7447", f"tls/127.0.0.1:{port}")
    out.write_text(text)
    return out


@pytest.fixture
def pki(tmp_path):
    ca = Authority(tmp_path / "certs")
    for cn in ("router", "uav1", "uav2", "ground", "ops", "stranger"):
        ca.leaf(cn)
    return ca


@pytest.fixture
def router(tmp_path, pki):
    """The example router (mutual TLS, access control) on a free loopback port."""
    port = free_port()
    conf = example("router.json5", pki.folder, tmp_path / "router.json5", port)
    session = open_session(BusConfig(mode="router", config_file=str(conf),
                                     multicast_scouting=False))
    try:
        yield f"tls/localhost:{port}"
    finally:
        session.close()


def tls_bus(pki: Authority, endpoint: str, cn: str | None, mode: str = "client",
            ca: Path | None = None) -> BusConfig:
    """A session config dialling ``endpoint`` over TLS, showing the certificate of ``cn``
    (None: none) and trusting ``ca`` (default: the test CA)."""
    z = {"transport/link/tls/root_ca_certificate": str(ca or pki.ca)}
    if cn is not None:
        z |= {"transport/link/tls/connect_private_key": str(pki.folder / f"{cn}-key.pem"),
              "transport/link/tls/connect_certificate": str(pki.folder / f"{cn}.pem"),
              "transport/link/tls/enable_mtls": True}
    return BusConfig(mode=mode, connect=(endpoint,), multicast_scouting=False, zenoh=z)


class Heard:
    """What a subscriber received: (key, payload) pairs."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.samples: list[tuple[str, bytes]] = []

    def __call__(self, sample) -> None:
        with self.lock:
            self.samples.append((str(sample.key_expr), sample.payload.to_bytes()))

    def payloads(self) -> list[bytes]:
        with self.lock:
            return [p for _, p in self.samples]


def wait_for(predicate, timeout_s: float = 10.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.05)
    return False


def test_access_control_lets_vehicles_publish_their_keys_and_the_ground_only_read(pki, router):
    sessions = []

    def session(cn: str, mode: str = "client"):
        s = open_session(tls_bus(pki, router, cn, mode))
        sessions.append(s)
        return s

    try:
        ground, ground2, stranger = session("ground"), session("ground"), session("stranger")
        uav1, uav2 = session("uav1", "peer"), session("uav2", "peer")  # as the daemons
        at_ground, at_stranger, at_uav1 = Heard(), Heard(), Heard()
        # The ground subscribes as pdcov watch does; pdcov/** is no key it may follow.
        keep = [ground.declare_subscriber("pdcov/*/status", at_ground),
                ground.declare_subscriber("pdcov/*/tiles", at_ground),
                stranger.declare_subscriber("pdcov/*/status", at_stranger),
                stranger.declare_subscriber("pdcov/**", at_stranger),
                uav1.declare_subscriber("pdcov/uav1/**", at_uav1),  # e.g. its frames input
                uav1.declare_queryable("pdcov/uav1/snapshot",
                                       lambda q: (q.reply(q.key_expr, b"SNAPSHOT"), q.drop())),
                uav1.liveliness().declare_token("pdcov/uav1/alive")]
        time.sleep(1.0)  # declarations reach the router
        uav1.put("pdcov/uav1/status", b"genuine")
        uav2.put("pdcov/uav1/status", b"forged by uav2")
        uav2.put("pdcov/uav2/status", b"uav2 genuine")
        ground2.put("pdcov/uav1/frames", b"forged by the ground")
        ground2.put("pdcov/uav1/tiles", b"forged by the ground")
        assert wait_for(lambda: len(at_ground.payloads()) >= 2)
        time.sleep(1.0)  # anything forged would have arrived by now
        assert sorted(at_ground.payloads()) == [b"genuine", b"uav2 genuine"]
        assert at_uav1.payloads() == [b"genuine"]  # its own put, nothing from the others
        assert at_stranger.payloads() == []
        replies = [r.ok.payload.to_bytes() for r in ground.get("pdcov/uav1/snapshot",
                                                                timeout=10.0) if r.ok]
        assert replies == [b"SNAPSHOT"]
        tokens = [str(r.ok.key_expr) for r in ground.liveliness().get("pdcov/*/alive",
                                                                     timeout=10.0) if r.ok]
        assert tokens == ["pdcov/uav1/alive"]
        assert [r for r in stranger.get("pdcov/uav1/snapshot", timeout=2.0) if r.ok] == []
        assert [r for r in stranger.liveliness().get("pdcov/*/alive", timeout=2.0)
                if r.ok] == []
        for e in keep:
            e.undeclare()
    finally:
        for s in reversed(sessions):
            s.close()


def test_without_an_accepted_certificate_nothing_connects(tmp_path, pki, router):
    other = Authority(tmp_path / "other-ca", name="someone else's CA")
    other.leaf("ground")
    port = router.rsplit(":", 1)[1]
    for bus, why in ((tls_bus(pki, router, None), "no client certificate"),
                     (tls_bus(other, router, "ground", ca=pki.ca), "another CA's certificate"),
                     (tls_bus(pki, router, "ground", ca=other.ca), "router not trusted"),
                     (BusConfig(mode="client", connect=(f"tcp/127.0.0.1:{port}",),
                                multicast_scouting=False), "plain TCP")):
        with pytest.raises(ConfigError, match="cannot open the Zenoh session"):
            s = open_session(bus)
            s.close()  # pragma: no cover - only reached when the test is about to fail
            pytest.fail(f"{why}: the session opened")


def test_tls_without_client_certificates(tmp_path, pki):
    """TLS as the only option: encrypted, the router authenticated by its certificate."""
    port = free_port()
    router = open_session(BusConfig(mode="router", listen=(f"tls/127.0.0.1:{port}",),
                                    multicast_scouting=False, zenoh={
        "transport/link/tls/listen_private_key": str(pki.folder / "router-key.pem"),
        "transport/link/tls/listen_certificate": str(pki.folder / "router.pem")}))
    sessions = []
    try:
        sub = open_session(tls_bus(pki, f"tls/localhost:{port}", None))
        pub = open_session(tls_bus(pki, f"tls/localhost:{port}", None, mode="peer"))
        sessions += [sub, pub]
        heard = Heard()
        s = sub.declare_subscriber("pdcov/**", heard)
        time.sleep(0.5)
        pub.put("pdcov/uav1/status", b"over TLS")
        assert wait_for(lambda: heard.payloads() == [b"over TLS"])
        s.undeclare()
        other = Authority(tmp_path / "other-ca", name="someone else's CA")
        with pytest.raises(ConfigError, match="cannot open"):
            open_session(tls_bus(pki, f"tls/localhost:{port}", None, ca=other.ca)).close()
    finally:
        for s in reversed(sessions):
            s.close()
        router.close()


def test_serve_and_watch_pass_their_tls_settings_to_zenoh(tmp_path, pki, router):
    """pdcov serve with bus.config_file = the aircraft example, pdcov watch with
    --zenoh-config = the ground example: the watcher gets the vehicle's grid through the
    router's access control; a watcher with the stranger's certificate gets nothing."""
    example("aircraft.json5", pki.folder, tmp_path / "aircraft.json5", 0)  # config_file
    ground = example("ground.json5", pki.folder, tmp_path / "ground.json5", 0)
    stranger = tmp_path / "stranger.json5"
    stranger.write_text(ground.read_text().replace("ground-key.pem", "stranger-key.pem")
                        .replace("ground.pem", "stranger.pem"))
    doc = dict(MISSION, bus={"mode": "peer", "connect": [router], "listen": [],
                             "multicast_scouting": False, "config_file": "aircraft.json5",
                             "status_period_s": 0.2},
               service={"state_dir": str(tmp_path / "state")})
    cfg = tmp_path / "uav1.yaml"
    cfg.write_text(yaml.safe_dump(doc))

    def watch(conf: Path) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-m", "pdcov.cli", "watch", "--zenoh-config", str(conf),
             "--mode", "client", "--zenoh-connect", router, "--once", "--wait-s", "8"],
            capture_output=True, text=True, timeout=60)

    with process(serve_args(cfg, "--connect", f"udpin:127.0.0.1:{free_port()}"),
                 tmp_path / "serve.log") as daemon:
        r = watch(ground)
        assert r.returncode == 0, r.stdout + r.stderr + (tmp_path / "serve.log").read_text()
        # The grid came (snapshot query and reply through the router), not only status.
        assert "(1 vehicle: uav1)" in r.stdout and "not yet received" not in r.stdout, \
            r.stdout
        r = watch(stranger)
        assert r.returncode == 1 and "uav1" not in r.stdout, r.stdout + r.stderr
        assert daemon.poll() is None
        assert stop(daemon) == 0
    assert "zenoh session: peer" in (tmp_path / "serve.log").read_text()


ITEMS = (MissionItem(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT, lat_deg=47.3978,
                     lon_deg=8.5457, z_m=10.0),)


def ask(session, vehicle: str, payload: bytes, timeout_s: float = 5.0) -> list[bytes]:
    return [r.ok.payload.to_bytes() for r in session.get(f"pdcov/{vehicle}/retask",
                                                         payload=payload, timeout=timeout_s)
            if r.ok is not None]


def test_only_the_authorised_ground_station_reaches_the_retask_key(tmp_path, pki, router):
    """Router ACL with mutual TLS: "ops" is answered (by the daemon: no autopilot on its
    link yet), "ground" (the readers' certificate) and a stranger get nothing: the query
    never reaches the daemon, whose log shows only the ops request."""
    example("aircraft.json5", pki.folder, tmp_path / "aircraft.json5", 0)
    doc = dict(MISSION, bus={"mode": "peer", "connect": [router], "listen": [],
                                 "multicast_scouting": False, "config_file": "aircraft.json5",
                                 "status_period_s": 0.2},
               service={"state_dir": str(tmp_path / "state"), "retask": True,
                        "retask_operator_keys": [write_pub(tmp_path).name]})
    cfg = tmp_path / "uav1.yaml"
    cfg.write_text(yaml.safe_dump(doc))
    log = tmp_path / "serve.log"
    request = signed(ITEMS, "uav1", time.time())
    with process(serve_args(cfg, "--connect", f"udpin:127.0.0.1:{free_port()}"),
                 log) as daemon:
        sessions = {cn: open_session(tls_bus(pki, router, cn)) for cn in
                    ("ops", "ground", "stranger")}
        try:
            end = time.monotonic() + 20
            answered: list[bytes] = []
            while not answered and time.monotonic() < end:  # until the daemon declared it
                answered = ask(sessions["ops"], "uav1", request, 2.0)
            assert [decode_retask_reply(a).reason for a in answered] == ["PDCOV_NO_AUTOPILOT"]
            assert ask(sessions["ground"], "uav1", request) == []
            assert ask(sessions["stranger"], "uav1", request) == []
        finally:
            for s in sessions.values():
                s.close()
        assert stop(daemon) == 0
    text = log.read_text()
    assert text.count("re-tasking request") == 1, text  # the daemon never saw the others


WILDCARDS = ("pdcov/**", "pdcov/*/retask", "pdcov/uav1/*", "pdcov/uav1/ret$*",
             "pdcov/uav1/retask", "**", "pdcov/*/*", "pdcov/uav1/**", "pdcov/uav1/$*t$*")


def test_no_key_expression_of_the_readers_or_a_stranger_reaches_the_retask_queryable(
        pki, router):
    """The shipped ACL allows exact keys only, so no wildcard of a query's own reaches a
    vehicle's retask queryable: Zenoh lets a query through when a rule's key expression
    includes the query's (a deny on pdcov/*/retask does not stop pdcov/**). "ground" and
    a stranger try every key expression above and a put on the key: nothing reaches the
    queryable nor a subscriber on it; "ops" reaches it by its exact key only; "ground"
    still gets the snapshot, mission, footprint and candidates replies."""
    sessions = []
    reached: list[tuple[str, str]] = []  # (kind, key expression) that reached uav1
    lock = threading.Lock()

    def session(cn: str, mode: str = "client"):
        s = open_session(tls_bus(pki, router, cn, mode))
        sessions.append(s)
        return s

    def answer(kind: str):
        def on_query(query) -> None:
            with lock:
                reached.append((kind, str(query.key_expr)))
            query.reply(f"pdcov/uav1/{kind}", kind.encode())
            query.drop()
        return on_query

    def asked(s, key: str, timeout_s: float = 1.5) -> list[tuple[str, str]]:
        with lock:
            reached.clear()
        replies = [r for r in s.get(key, payload=b"mission", timeout=timeout_s) if r.ok]
        with lock:
            assert len(replies) <= len(reached)
            return list(reached)

    kinds = ("retask", "snapshot", "mission", "footprint", "candidates", "status")
    try:
        uav1 = session("uav1", "peer")
        heard = Heard()
        keep = [uav1.declare_queryable(f"pdcov/uav1/{k}", answer(k)) for k in kinds]
        keep.append(uav1.declare_subscriber("pdcov/uav1/retask", heard))
        ground, stranger, ops = session("ground"), session("stranger"), session("ops")
        time.sleep(1.0)  # declarations reach the router
        for who, s in (("ground", ground), ("stranger", stranger)):
            for key in WILDCARDS:
                assert asked(s, key) == [], f"{who}'s query on {key} reached uav1"
            s.put("pdcov/uav1/retask", b"mission")
        for key in WILDCARDS:
            if key != "pdcov/uav1/retask":
                assert asked(ops, key) == [], f"ops's query on {key} reached uav1"
        assert asked(ops, "pdcov/uav1/retask", 3.0) == [("retask", "pdcov/uav1/retask")]
        for kind in ("snapshot", "mission", "footprint", "candidates"):
            assert asked(ground, f"pdcov/uav1/{kind}", 3.0) == [(kind, f"pdcov/uav1/{kind}")]
            assert asked(stranger, f"pdcov/uav1/{kind}") == []
        assert asked(ground, "pdcov/uav1/status") == []  # published, never queried
        time.sleep(0.5)
        assert heard.payloads() == []
        for e in keep:
            e.undeclare()
    finally:
        for s in reversed(sessions):
            s.close()
