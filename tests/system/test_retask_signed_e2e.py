"""Command authority end to end: a real daemon (``pdcov serve``) with an autopilot
stand-in on its MAVLink link (tests/support/autopilot_standin.py) over a real Zenoh router on
loopback. ``pdcov upload --bus`` sends a signed in-bounds plan, which the autopilot
accepts and the pilot is told of (STATUSTEXT); an out-of-bounds plan, queries through
wildcard key expressions and a replay (also after the daemon restarted) are refused and
never reach the autopilot."""

from __future__ import annotations

import json
import time

import zenoh

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.retask import decode_retask_reply
from pdcov.bus.session import BusConfig, open_session
from pdcov.cli import main as pdcov_main
from pdcov.core.geodesy import Origin
from pdcov.planning.plan_files import wpl_text
from tests.support.autopilot_standin import AutopilotStandIn
from tests.support.link_feed import MISSION
from tests.support.retask_harness import FAR, WP
from tests.support.retask_keys import KEY, signed, write_key, write_pub
from tests.support.serve_harness import (
    Subscriber,
    free_port,
    process,
    router,
    serve_args,
    serve_config,
    stop,
)


def ask(session, key: str, payload: bytes) -> list[str]:
    """The reasons of the re-tasking replies to ``get key`` (other replies skipped)."""
    out = []
    for r in session.get(key, payload=payload, timeout=5.0,
                         consolidation=zenoh.ConsolidationMode.NONE):
        if r.ok is None:
            continue
        try:
            reply = decode_retask_reply(r.ok.payload.to_bytes())
        except BusPayloadError:
            continue  # a snapshot, status or mission reply to a wildcard
        out.append("ACCEPTED" if reply.accepted else reply.reason)
    return out


def test_signed_plan_flies_others_never_reach_the_autopilot(tmp_path, capsys) -> None:
    zport, mport = free_port(), free_port()
    write_pub(tmp_path / "vehicle")
    key_file = write_key(tmp_path / "ground")
    cfg = serve_config(MISSION, tmp_path / "m.yaml", zenoh_port=zport,
                       state_dir=tmp_path / "state", retask=True,
                       retask_operator_keys=["vehicle/operator.pub"])
    o = MISSION["origin"]
    plan = tmp_path / "refly.waypoints"
    plan.write_text(wpl_text((WP,), Origin(o["lat_deg"], o["lon_deg"], o["ground_alt_msl_m"])))
    bus = ["--config", str(cfg), "--mode", "client", "--zenoh-connect",
           f"tcp/127.0.0.1:{zport}"]
    zrouter = router(zport)
    try:
        with process(serve_args(cfg, "--connect", f"udpin:127.0.0.1:{mport}"),
                     tmp_path / "serve.log") as daemon:
            ap = AutopilotStandIn(mport)
            sub = Subscriber(zport, "fuzz")
            s = open_session(BusConfig(mode="client", connect=(f"tcp/127.0.0.1:{zport}",),
                                       multicast_scouting=False))
            try:
                sub.wait(lambda st: st["link"]["state"] == "connected", 30.0, "connected")
                # No key: the ground station refuses to send, and says why.
                assert pdcov_main(["upload", "--bus", "fuzz", "--plan", str(plan), *bus]) == 1
                assert "no operator key" in capsys.readouterr().err
                assert pdcov_main(["upload", "--bus", "fuzz", "--plan", str(plan),
                                   "--operator-key", str(key_file), *bus]) == 0
                out = capsys.readouterr().out
                assert "accepted: MAV_MISSION_ACCEPTED" in out, out
                deadline = time.monotonic() + 5.0
                while not ap.texts and time.monotonic() < deadline:
                    time.sleep(0.05)
                assert ap.texts == [(5, f"pdcov: mission 2 items key {KEY.id[:8]} ok")]
                assert ap.missions == [2]  # ArduPilot's home, then the waypoint
                # Out of bounds, through wildcards, replayed: refused, nothing uploaded.
                assert ask(s, "pdcov/fuzz/retask", signed((WP, FAR), unix_s=time.time())) \
                    == ["PDCOV_OUT_OF_BOUNDS"]
                for key in ("pdcov/**", "pdcov/fuzz/*", "pdcov/fuzz/ret$*"):
                    assert ask(s, key, signed((WP,), unix_s=time.time())) \
                        == ["PDCOV_WILDCARD"], key
                again = signed((WP,), unix_s=time.time())
                assert ask(s, "pdcov/fuzz/retask", again) == ["ACCEPTED"]
                assert ask(s, "pdcov/fuzz/retask", again) == ["PDCOV_REPLAYED"]
                assert ap.received["MISSION_COUNT"] == 2 and ap.missions == [2, 2]
                st = sub.wait(lambda st: st["faults"].get("retask_refused") == 5, 10.0,
                              "the refusals counted")
                assert st["retask"]["refused"] == {"PDCOV_OUT_OF_BOUNDS": 1,
                                                   "PDCOV_REPLAYED": 1, "PDCOV_WILDCARD": 3}
                assert st["retask"]["last"]["key_id"] == KEY.id
            finally:
                s.close()
                sub.close()
                ap.close()
            assert stop(daemon) == 0
        # A restarted daemon reads the nonces back: the replay is still refused.
        with process(serve_args(cfg, "--connect", f"udpin:127.0.0.1:{mport}"),
                     tmp_path / "serve2.log") as daemon:
            s = open_session(BusConfig(mode="client", connect=(f"tcp/127.0.0.1:{zport}",),
                                       multicast_scouting=False))
            try:
                answered: list[str] = []
                deadline = time.monotonic() + 20.0
                while not answered and time.monotonic() < deadline:  # until it declared it
                    answered = ask(s, "pdcov/fuzz/retask", again)
                assert answered == ["PDCOV_REPLAYED"]
            finally:
                s.close()
            assert stop(daemon) == 0
    finally:
        zrouter.close()
    nonces = json.loads((tmp_path / "state" / "retask_nonces.json").read_text())
    # The verified requests' nonces (upload, out of bounds, again), kept for a restart; the
    # wildcard queries were refused before their signature was looked at.
    assert len(nonces["nonces"]) == 3
    assert "PDCOV_WILDCARD" in (tmp_path / "serve.log").read_text()
