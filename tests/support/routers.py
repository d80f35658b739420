"""Zenoh routers as processes of their own, as zenohd runs on a ground station: killed and
started again by the tests of docs/ground-station.md "Topologies".

``python tests/support/routers.py PORT [ENDPOINT ...]`` runs a router listening on
tcp/127.0.0.1:PORT (multicast scouting off, nothing leaves loopback) that connects to the
other routers' ENDPOINTs, until SIGTERM or SIGINT; it prints one line once it listens."""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def router_process(port: int, log: Path, *connect: str) -> Iterator[subprocess.Popen]:
    """A router process on tcp/127.0.0.1:``port`` linked to the routers at ``connect``,
    listening when this returns; its output is appended to ``log`` (a restarted router
    keeps one log); killed (SIGKILL) at the end if still running."""
    from tests.support.harness import child

    start = log.stat().st_size if log.exists() else 0
    with child([sys.executable, __file__, str(port), *connect], log, "ab") as p:
        end = time.monotonic() + 60.0
        while f"router listening on tcp/127.0.0.1:{port}" not in log.read_text()[start:]:
            if p.poll() is not None or time.monotonic() > end:
                raise AssertionError(f"no router on port {port}: {log.read_text()[-2000:]}")
            time.sleep(0.1)
        yield p


def main(argv: list[str]) -> None:
    from pdcov.bus.session import BusConfig, open_session

    port, connect = int(argv[0]), tuple(argv[1:])
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    session = open_session(BusConfig(mode="router", listen=(f"tcp/127.0.0.1:{port}",),
                                     connect=connect, multicast_scouting=False))
    print(f"router listening on tcp/127.0.0.1:{port}", flush=True)
    try:
        stop.wait()
    finally:
        session.close()


if __name__ == "__main__":
    main(sys.argv[1:])
