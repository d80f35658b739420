"""``pdcov serve``: the onboard daemon (docs/service.md)."""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pdcov.service.settings import ServeConfig


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "serve", help="the onboard daemon: MAVLink in, coverage over Zenoh out",
        description="Read the autopilot's telemetry, update the coverage grid at the camera's "
                    "frames, publish it over Zenoh (docs/protocol.md), checkpoint it, until "
                    "SIGTERM/SIGINT.")
    p.add_argument("--config", required=True, type=Path, help="mission config YAML")
    p.add_argument("--connect", action="append", metavar="URL",
                   help="MAVLink link (repeatable; replaces link.connect): udpin:0.0.0.0:14550, "
                        "udpout:HOST:PORT, tcp:HOST:PORT, /dev/ttyAMA0,921600, "
                        "serial:/dev/ttyAMA0:921600")
    p.add_argument("--zenoh-connect", action="append", metavar="ENDPOINT",
                   help="Zenoh endpoint to connect to (repeatable; replaces bus.connect), "
                        "e.g. tcp/192.168.1.10:7447")
    p.add_argument("--zenoh-listen", action="append", metavar="ENDPOINT",
                   help="Zenoh endpoint to listen on (repeatable; replaces bus.listen)")
    p.add_argument("--state-dir", help="checkpoints and recordings (replaces "
                                       "service.state_dir)")
    p.add_argument("--check", action="store_true",
                   help="validate the config, camera, detector, domain and state directory, "
                        "then exit (0 ok, 2 with the reason)")
    p.set_defaults(func=run_serve)


def run_serve(args: argparse.Namespace) -> int:
    from pdcov.errors import ConfigError
    from pdcov.service.settings import load_serve_config, replace_endpoints

    cfg = replace_endpoints(load_serve_config(args.config), connect=args.connect,
                            zenoh_connect=args.zenoh_connect, zenoh_listen=args.zenoh_listen,
                            state_dir=args.state_dir)
    state = Path(cfg.service.state_dir)
    if args.check:
        return _check(args, cfg, state)
    try:
        state.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=state):
            pass
    except OSError as exc:
        raise ConfigError(f"service.state_dir {state}: not a writable folder "
                          f"({exc.strerror or exc})") from None
    if not cfg.link.connect:
        raise ConfigError(f"{args.config}: no MAVLink link: set link.connect or give "
                          "--connect URL")
    import asyncio

    from pdcov.service.daemon import Daemon
    from pdcov.service.journal_log import setup_logging

    setup_logging()
    import faulthandler
    import signal
    faulthandler.register(signal.SIGUSR1)  # `kill -USR1 PID`: every thread's stack to the log
    os.environ.setdefault("MAVLINK20", "1")
    return asyncio.run(Daemon(cfg).run())


def _check(args: argparse.Namespace, cfg: ServeConfig, state: Path) -> int:
    """``--check``: validate everything the daemon would use, creating and changing nothing
    on disk; 0 and one line, or a ConfigError."""
    from pdcov.bus.session import zenoh_config
    from pdcov.errors import ConfigError
    from pdcov.service.memory_budget import memory_check, memory_limit_bytes
    from pdcov.service.state_files import check_state_dir

    warnings = list(cfg.mission.warnings)
    state_warning = check_state_dir(state)
    if state_warning is not None:
        warnings.append(state_warning)
    for w in warnings:
        print(f"pdcov serve --check: WARNING: {w}", file=sys.stderr)
    grid = cfg.mission.new_mission_grid()
    memory = memory_check(cfg.mission, grid.n_free,
                          grid.geometry.n_rows * grid.geometry.n_cols,
                          memory_limit_bytes())
    if memory.refusal is not None:
        raise ConfigError(f"{args.config}: {memory.refusal}")
    if memory.warning is not None:
        print(f"pdcov serve --check: WARNING: {memory.warning}", file=sys.stderr)
    zenoh_config(cfg.bus)
    if (cfg.link.signing_key_file and
            cfg.link.signing_key_bytes(cfg.base_dir) is None):
        raise ConfigError(f"link.signing_key_file: cannot read 64 hex digits from "
                          f"{cfg.link.signing_key_file}")
    print(f"pdcov serve --check: {args.config} ok: vehicle {cfg.mission.vehicle_id}, "
          f"grid {grid.geometry.n_rows} x {grid.geometry.n_cols} cells "
          f"({grid.n_free} free), "
          + ", ".join(f"camera {c.name} {c.camera.width_px}x{c.camera.height_px} at "
                      f"{c.frame_rate_hz:g} Hz" for c in cfg.mission.cameras)
          + ", frames by "
          f"{cfg.frame_source}, links {list(cfg.link.connect) or 'none'}, zenoh "
          f"{cfg.bus.mode}, state dir {state}")
    return 0
