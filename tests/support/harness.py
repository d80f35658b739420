"""What a run with real processes needs, for the benchmarks and the end-to-end tests alike:
free loopback ports, an in-process Zenoh router, child processes that always end with the
run, the ``pdcov serve`` command line and its stop, and the small mission the simulated
flights survey (a 30 m square at 1 m cells, a 640x480 camera at 5 Hz on a gimbal).

The benchmarks import it from here (tests.support), the tests never import benchmarks;
tests/support/serve_harness.py builds the tests' Zenoh subscriber and config writer on it.
"""

from __future__ import annotations

import contextlib
import copy
import os
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pdcov.bus.session import BusConfig, open_session

ROOT = Path(__file__).resolve().parents[2]

SMALL_MISSION: dict[str, Any] = {
    "origin": {"lat_deg": 47.397742, "lon_deg": 8.545594, "ground_alt_msl_m": 488.0},
    "domain": {"polygon_enu_m": [[0, 0], [30, 0], [30, 30], [0, 30]], "cell_size_m": 1.0},
    "camera": {"width_px": 640, "height_px": 480,
               "K": [[480.0, 0.0, 319.5], [0.0, 480.0, 239.5], [0.0, 0.0, 1.0]],
               "distortion_model": "plumb_bob",
               "distortion_coeffs": [-0.05, 0.01, 0.0, 0.0, 0.0], "frame_rate_hz": 5},
    "mount": {"type": "gimbal", "attitude_frame": "auto"},
    "detector": "illustrative",
}
"""The mission document (pdcov.config) of the simulated flights; ``small_mission`` copies
it. Its origin is the simulator's default home."""


def small_mission(**sections: Any) -> dict[str, Any]:
    """A fresh copy of SMALL_MISSION with ``sections`` (vehicle_id, coverage, ...) set."""
    return {**copy.deepcopy(SMALL_MISSION), **sections}


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A port on 127.0.0.1 free now (TCP by default; ``socket.SOCK_DGRAM`` for UDP)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def router(port: int) -> Any:
    """An in-process Zenoh router listening on tcp/127.0.0.1:``port`` (no multicast
    scouting); close it with ``.close()``."""
    return open_session(BusConfig(mode="router", listen=(f"tcp/127.0.0.1:{port}",),
                                  multicast_scouting=False))


@contextlib.contextmanager
def child(args: list[str], log: Path, mode: str = "wb", *,
          grace_s: float = 0.0) -> Iterator[subprocess.Popen]:
    """A process in its own group with stdout and stderr in ``log`` (opened with ``mode``)
    and the simulator package on its PYTHONPATH. At the end, if it still runs, its group is
    killed: with SIGKILL, or with ``grace_s`` > 0 SIGTERM first and SIGKILL after
    ``grace_s`` seconds."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT / "sitl"), os.environ.get("PYTHONPATH", "")]))
    with log.open(mode) as out:
        p = subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT, env=env,
                             start_new_session=True)
        try:
            yield p
        finally:
            if p.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.pid, signal.SIGTERM if grace_s > 0 else signal.SIGKILL)
                if grace_s > 0:
                    try:
                        p.wait(timeout=grace_s)
                    except subprocess.TimeoutExpired:
                        with contextlib.suppress(ProcessLookupError):
                            os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=20)


def serve_args(config: Path, *more: str) -> list[str]:
    """The command line of ``pdcov serve --config config`` with this interpreter."""
    return [sys.executable, "-m", "pdcov.cli", "serve", "--config", str(config), *more]


def stop(p: subprocess.Popen, timeout_s: float = 20.0) -> int:
    """SIGTERM and wait: the daemon writes its checkpoint and exits 0."""
    p.send_signal(signal.SIGTERM)
    return p.wait(timeout=timeout_s)
