"""Every topology of docs/ground-station.md "Topologies" with the defaults (bus.mode auto,
`pdcov watch` without --mode): the real daemon, routers as processes of their own
(tests/support/routers.py), `pdcov watch` as a process, all on 127.0.0.1 with multicast scouting
off. The defect of issue 22 was a watcher and a daemon, both peers listening nowhere, that
exchanged nothing through a router: each `--once` below exits 1 with an empty table then."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
import urllib.request

from tests.support.harness import small_mission
from tests.support.routers import router_process
from tests.support.serve_harness import (
    fly_args,
    free_port,
    process,
    serve_args,
    serve_config,
    small_plan,
)
from tests.support.watch_fixtures import read_line, stop_watcher

SIM = small_mission(vehicle_id="sim1")
AUTO = {"mode": None, "listen": None}
"""The daemon's bus with its defaults: mode auto, listening nowhere."""


def watch(*args: str) -> list[str]:
    return [sys.executable, "-m", "pdcov.cli", "watch", "--no-multicast-scouting", *args]


def once(endpoint: str, *more: str) -> str:
    """`pdcov watch --once` through ``endpoint``: its output; fails unless it saw sim1."""
    out = subprocess.run(watch("--once", "--vehicle", "all", "--zenoh-connect", endpoint,
                               "--wait-s", "10", *more),
                         capture_output=True, text=True, timeout=90)
    assert out.returncode == 0, out.stdout + out.stderr
    assert any(line.startswith("|sim1 ") for line in out.stdout.splitlines()), out.stdout
    return out.stdout + out.stderr


def frames_of(text: str) -> int:
    """The frames column of sim1's row in a `pdcov watch` table."""
    row = next(line for line in text.splitlines() if line.startswith("|sim1 "))
    return int(row.split("|")[6])


def test_daemon_and_watcher_on_one_host_without_router(tmp_path):
    # The daemon listens (a peer, as on the field LAN) and no router runs: the watcher
    # connects to the daemon itself, as a client (its default) and as a peer.
    port = free_port()
    cfg = serve_config(SIM, tmp_path / "m.yaml", zenoh_port=port, state_dir=tmp_path / "st",
                       session={"mode": None, "connect": [],
                                "listen": [f"tcp/127.0.0.1:{port}"]})
    with process(serve_args(cfg, "--connect", f"udpin:127.0.0.1:{free_port()}"),
                 tmp_path / "serve.log"):
        out = once(f"tcp/127.0.0.1:{port}")
        assert "zenoh session client (auto)" in out
        once(f"tcp/127.0.0.1:{port}", "--mode", "peer")  # a peer reaches a listening peer
    log = (tmp_path / "serve.log").read_text()
    assert f"zenoh session: peer (auto), connect [], listen [tcp/127.0.0.1:{port}]" in log


def test_watcher_with_no_vehicle_says_why(tmp_path):
    port = free_port()
    with router_process(port, tmp_path / "router.log"):
        out = subprocess.run(watch("--once", "--zenoh-connect", f"tcp/127.0.0.1:{port}",
                                   "--wait-s", "2"), capture_output=True, text=True,
                             timeout=60)
    assert out.returncode == 1, out.stdout + out.stderr
    text = " ".join(out.stdout.split())
    assert "no vehicle heard 2 s after connecting; this session: client (auto)" in text, text
    assert "is a daemon running with the same router" in text, text


def test_flight_through_two_routers_web_map_and_router_restart(tmp_path):
    # Router B links to router A; the daemon (defaults: a client of A) flies; watchers
    # follow through A and through B, the web map through A; A is killed and started
    # again mid-flight and the watcher on A carries on.
    pa, pb, mport = free_port(), free_port(), free_port()
    a, b = f"tcp/127.0.0.1:{pa}", f"tcp/127.0.0.1:{pb}"
    (tmp_path / "plan").mkdir()
    plan = small_plan(tmp_path / "plan", SIM)
    cfg = serve_config(SIM, tmp_path / "m.yaml", zenoh_port=pa, state_dir=tmp_path / "st",
                       session=AUTO)
    ra_log = tmp_path / "router-a.log"
    with router_process(pb, tmp_path / "router-b.log", a), \
            process(serve_args(cfg, "--connect", f"udpin:127.0.0.1:{mport}"),
                    tmp_path / "serve.log") as daemon:
        ra = router_process(pa, ra_log)  # after B and the daemon: both wait for it
        ra.__enter__()
        try:
            with process(fly_args(cfg, plan, tmp_path / "fly", f"udpout:127.0.0.1:{mport}",
                                  speed=2.0), tmp_path / "fly.log") as fly:
                long = subprocess.Popen(
                    watch("--plain", "--zenoh-connect", a, "--record", str(tmp_path / "rec")),
                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
                try:
                    line = read_line(long, 60.0)
                    assert "(client (auto), connect [" in line, line
                    assert frames_of(once(a)) >= 0  # (b) daemon -> router <- watcher
                    assert frames_of(once(b)) >= 0  # (c) daemon -> A - B <- watcher
                    web_map_shows_sim1(a)  # (d)
                    ra.__exit__(None, None, None)  # SIGKILL: the router is gone
                    time.sleep(3.0)
                    ra = router_process(pa, ra_log)
                    ra.__enter__()
                    restarted = time.time()
                    during = frames_of(once(a))
                    assert fly.poll() is None, "the flight ended before the restart's test"
                    assert fly.wait(timeout=300) == 0, (tmp_path / "fly.log").read_text()[-2000:]
                    time.sleep(2.0)
                    after = frames_of(once(b))  # after the flight, through the linked router
                    assert after > during > 0, (during, after)
                finally:
                    stop_watcher(long)
            statuses = [json.loads(x) for x in
                        (tmp_path / "rec" / "sim1" / "status.jsonl").read_text().splitlines()]
            assert sum(s["recv_unix_s"] > restarted for s in statuses) >= 10, \
                "the watcher on the restarted router heard no status after the restart"
            assert daemon.poll() is None, (tmp_path / "serve.log").read_text()[-3000:]
        finally:
            ra.__exit__(None, None, None)
    log = (tmp_path / "serve.log").read_text()
    assert f"zenoh session: client (auto), connect [{a}], listen []" in log


def web_map_shows_sim1(endpoint: str) -> None:
    """`pdcov watch --web` through ``endpoint``: its /state.json lists sim1 (within 30 s)."""
    env = dict(os.environ, PDCOV_WEB_TOKEN="topologies-test-token-0123")
    p = subprocess.Popen(watch("--plain", "--web", "127.0.0.1:0", "--zenoh-connect", endpoint),
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        url = None
        end = time.monotonic() + 60
        while url is None and time.monotonic() < end:
            m = re.search(r"web map at (http://\S+)\?token=(\S+)", read_line(p, 60.0))
            url = m and f"{m.group(1)}state.json?token={m.group(2)}"
        assert url is not None, "no web map address printed"
        ids: list[str] = []
        while "sim1" not in ids and time.monotonic() < end:
            with urllib.request.urlopen(url, timeout=10) as r:
                ids = [v["id"] for v in json.load(r)["vehicles"]]
            time.sleep(0.5)
        assert "sim1" in ids, ids
    finally:
        p.send_signal(signal.SIGTERM)
        p.wait(timeout=60)
