"""The security checks of docs/reliability.md's "Security" section: each a test on loopback
with real processes and sessions (``SECURITY_TESTS``, one pytest run) or the systemd
unit's exposure score; ``python -m benchmarks.fleet --write-docs`` runs them and writes
the table beside the fleet figures."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import time

from tests.support.harness import ROOT

SECURITY_TESTS = ("tests/system/test_security_zenoh.py",
                  "tests/simulators/test_security_mavlink.py", "tests/unit/test_status_size.py",
                  "tests/unit/test_web_auth.py", "tests/integration/test_web_auth_watch.py",
                  "tests/unit/test_bus_hostile.py", "tests/unit/test_web_hostile.py",
                  "tests/system/test_web_hostile_zenoh.py", "tests/unit/test_record_errors.py",
                  "tests/unit/test_security_daemon.py",
                  "tests/system/test_security_daemon_zenoh.py",
                  "tests/unit/test_watcher_pinning.py", "tests/system/test_watch_hostile.py")
SECURITY_ROWS = (  # check, how it is tested (docs/reliability.md "Security")
    ('Zenoh over TLS',
     "a TLS router; a client trusting the CA receives a peer's put; a client trusting "
     'another CA cannot connect (the router is authenticated)'),
    ('Mutual TLS',
     'the example router `systemd/zenoh/router.json5` (`enable_mtls`): no client '
     'certificate, a certificate of another CA, plain TCP to the TLS port: the session '
     'does not open'),
    ('Access control',
     "the same router's default-deny ACL by certificate common name: the ground "
     "(`ground`) receives uav1's and uav2's status, gets uav1's snapshot reply and "
     'liveliness token; its puts into `pdcov/uav1/frames` and `/tiles` reach nobody; '
     "uav2's put into `pdcov/uav1/status` reaches nobody; a certificate of the CA with "
     'another name (`stranger`) receives, queries and sees nothing; no query of `ground` '
     'or `stranger` on `pdcov/**`, `pdcov/*/retask`, `pdcov/uav1/*`, `pdcov/uav1/ret$*`, '
     '`pdcov/uav1/retask`, `**`, `pdcov/*/*` nor a put on the key reaches uav1\'s retask '
     'queryable (the ACL allows exact keys only: Zenoh passes a query whose key '
     'expression a rule *includes*, so a deny of `pdcov/*/retask` beside an allow of '
     '`pdcov/**` let wildcards through); `ops` reaches it by `pdcov/uav1/retask` only'),
    ('Config passed through',
     '`pdcov serve` with `bus.config_file` = `systemd/zenoh/aircraft.json5` and `pdcov '
     'watch --once --zenoh-config systemd/zenoh/ground.json5` through that router: the '
     "watcher gets the vehicle's grid; with the stranger's certificate it gets no "
     'vehicle'),
    ('MAVLink 2 signing',
     '`pdcov serve` with `link.signing_key` and `pdcov-sitl fly --signing-key`: '
     'telemetry used, every message the daemon sent signed with the key; unsigned '
     'telemetry and telemetry signed with another key: 0 messages taken, counted in '
     '`link.bad_messages`, no frame'),
    ('Nothing that moves the aircraft',
     'every message the daemon sent during a flight, read by a TCP tap between daemon '
     'and simulator: HEARTBEAT (onboard controller, 1/191), COMMAND_LONG with '
     'SET_MESSAGE_INTERVAL / REQUEST_MESSAGE only, PARAM_REQUEST_READ/LIST, '
     'NAMED_VALUE_FLOAT, STATUSTEXT'),
    ('No listening port unless configured',
     "the daemon's sockets in `/proc/PID/net` during the flight (MAVLink over a TCP "
     'client link, `bus.listen: []`, no multicast scouting): no listening TCP socket, '
     'no receiving UDP socket'),
    ('Writes only under its state directory',
     'files the daemon holds open for writing during the flight (`/proc/PID/fdinfo`): '
     'only under `service.state_dir`; an empty HOME, working directory and TMPDIR stay '
     'empty'),
    ('Web map access',
     '`pdcov watch --web` on 127.0.0.1: the page, its assets, `/state.json`, `/events` '
     'and basemap tiles answer 401 (one line of plain text) with no token or a wrong one '
     '(query, cookie, bearer), 200 with the right one; the tokened page sets an HttpOnly, '
     'SameSite=Strict session cookie; a foreign Host header (DNS rebinding) gets 403 even '
     'with the token; a token file group or others have any access to is refused (exit '
     '2). No TLS '
     'in pdcov: a trusted network or a TLS reverse proxy (docs/ground-station.md '
     '"Access")'),
    ('Status within 1 kB/s',
     "full and brief statuses (docs/protocol.md): a minute of a flying daemon's "
     'statuses averages under 1000 B/s (tests/unit/test_status_size.py); per vehicle in the '
     "fleet above on the daemon's clock: see its status column (a checkpoint's progress "
     'no longer makes its status full, tests/simulators/test_fleet.py)'),
    ('Forged coverage on the default bus',
     "`pdcov watch` as a process through a real router, a rogue session beside the "
     "vehicle's publisher: tiles with the vehicle's next seq and every cell at P_D 1, "
     "as a plain put and stamped with the rogue's own source: the recorded grid equals "
     "the daemon's cell for cell, the coverage shown is the daemon's, `also claims this "
     "vehicle` and `bus not secured` shown; a rogue answering the snapshot query too: "
     'the vehicle contested, no coverage shown for it; in memory: rechecks at most every '
     "10 s, a restarted daemon's new session followed, forged tiles stamped with the "
     "daemon's own id caught by the status cross-check, the 83-byte replayed tiles "
     'message dropped after one snapshot, 64 vehicles at most, merged counts in int64, '
     "the ground station's headline threshold and grid"),
    ('Hostile payloads',
     'every status, tiles, snapshot, footprint and mission field the watcher and the web '
     'map read, of the wrong type, out of range, NaN / Infinity / 1e400 or beyond a bound '
     '(payload bytes per kind, 64 thresholds, 16 M cells): refused naming the key and the '
     'field, with a reason to count; a 0.3 MB snapshot and a tiles message declaring 25 M '
     "cells: refused from their headers, nothing inflated; a rogue session's statuses "
     '(`{"abc": 0.5}`, `["x"]`, `Infinity`, 5,500 thresholds) on the default bus: `pdcov '
     "watch --web` keeps running, its map strict JSON and uav1's figures its daemon's"),
    ('Web map under load',
     '40 live-event clients and 10 `/state.json` readers: the state built once per '
     'change, not once per client; non-finite values reach the page as null; an update '
     'the page cannot read shows a banner (app.js run by node)'),
    ('Recorder on a failing disk',
     '`--record` with writes failing (ENOSPC, EIO, short writes, `/dev/full`): nothing '
     'raised, logged once per episode, counted; the recording complete once the disk '
     'takes writes again; the backlog bounded (64 MiB), what overflows counted'),
    ('MAVLink answered to the autopilot only',
     '`pdcov serve` on a UDP server link (`link.system_id: 1`), 3,000 rogue senders from '
     'distinct ports (another autopilot, a GCS, another component of the vehicle, junk) '
     'before and after the autopilot: they get no datagram back, the autopilot gets '
     "HEARTBEAT and SET_MESSAGE_INTERVAL, the link writes to one address (at most 4)"),
    ('Snapshot queries rate-limited',
     'a real-Zenoh flood of 40 queries from a session declaring its source info and 40 '
     'anonymous ones: 3 and 1-3 snapshots, a `rate limited:` error reply for the rest, '
     'counted in `faults.snapshot_queries_refused`; a third session still gets its '
     'snapshot; the token buckets stepped in memory (burst, rate, 64 requesters, '
     '128 KiB/s in all)'),
    ('Publications carry their source',
     "every status and tiles sample, through a router and peer to peer, carries the "
     "daemon session's zid (the `replier_id` of its snapshot reply) and consecutive "
     'sequence numbers per key'),
    ('Checkpoint of another vehicle',
     "a state directory holding uav1's checkpoint, started as uav2: set aside whole, the "
     'log line names uav1, the grid starts empty; renamed back, it resumes under uav1'),
    ('systemd hardening',
     '`systemd-analyze security --offline=true systemd/pdcov.service` (directives and '
     'why: docs/operations.md section 4)'),
)


def security_checks() -> dict[str, str]:
    """Run the security tests (pytest's last line and wall time) and score the unit
    (``systemd-analyze security --offline=true``, when systemd-analyze is installed)."""
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                        *SECURITY_TESTS], cwd=ROOT, capture_output=True, text=True)
    out = {"tests": (r.stdout.strip().splitlines() or ["no output"])[-1].strip("= "),
           "tests_wall_s": f"{time.monotonic() - t0:.0f}"}
    if shutil.which("systemd-analyze"):
        a = subprocess.run(["systemd-analyze", "security", "--offline=true",
                            "systemd/pdcov.service"], cwd=ROOT, capture_output=True, text=True)
        m = re.search(r"Overall exposure level for \S+: ([0-9.]+) (\w+)", a.stdout)
        v = subprocess.run(["systemd-analyze", "--version"], capture_output=True, text=True)
        out["systemd"] = (f"{m.group(1)} ({m.group(2)})" if m else "not scored") + \
            f", {v.stdout.split(chr(10))[0]}"
    else:
        out["systemd"] = "systemd-analyze not installed here"
    return out


def security_table(sec: dict[str, str]) -> str:
    """The checks with the tests' verdict (all or none: one pytest run covers them)."""
    ok = "passed" in sec["tests"] and not re.search(r"failed|error", sec["tests"])
    lines = ["| check | how it is tested | result |", "|---|---|---|"]
    for check, how in SECURITY_ROWS:
        result = "pass" if ok else "see the test summary above"
        if check == "systemd hardening":
            result = f"{sec['systemd']} (aim 2.0 or lower)"
        lines.append(f"| {check} | {how} | {result} |")
    return "\n".join(lines)
