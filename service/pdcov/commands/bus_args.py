"""The Zenoh options a ground command shares (``pdcov watch``, ``pdcov upload --bus``): the
mission config's bus section with the command line's endpoints, mode and TLS file."""

from __future__ import annotations

import argparse
from dataclasses import replace
from typing import TYPE_CHECKING

from pdcov.errors import ConfigError

if TYPE_CHECKING:
    from pdcov.bus.session import BusConfig
    from pdcov.config.mission import Mission


def add_bus_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mode", choices=("auto", "peer", "client"),
                   help="Zenoh session mode (default: the config's bus.mode, else auto: a "
                        "client when connecting somewhere and listening nowhere, as to a "
                        "router, else a peer with multicast scouting)")
    p.add_argument("--zenoh-connect", action="append", metavar="ENDPOINT",
                   help="Zenoh endpoint to connect to, e.g. tcp/192.168.10.1:7447 "
                        "(repeatable; replaces the config's)")
    p.add_argument("--zenoh-listen", action="append", metavar="ENDPOINT",
                   help="Zenoh endpoint to listen on (repeatable; replaces the config's)")
    p.add_argument("--zenoh-config", metavar="FILE",
                   help="Zenoh JSON5 config read first (TLS certificates of this ground "
                        "station; replaces the config's bus.config_file)")
    p.add_argument("--no-multicast-scouting", action="store_true",
                   help="do not look for peers and routers by multicast")


def bus_of(args: argparse.Namespace, mission: Mission | None) -> BusConfig:
    """The ground session's bus config: the mission's bus section (or the defaults) with
    the command line's options."""
    from pathlib import Path

    from pdcov.bus.session import BusConfig, bus_config_from_dict

    bus = (bus_config_from_dict(mission.raw.get("bus"), mission.source) if mission
           else BusConfig())
    bus = bus.with_endpoints(args.zenoh_connect, args.zenoh_listen)
    if args.zenoh_config is not None:
        if not Path(args.zenoh_config).is_file():
            raise ConfigError(f"--zenoh-config {args.zenoh_config}: no such file")
        bus = replace(bus, config_file=str(args.zenoh_config))
    if args.mode:
        bus = replace(bus, mode=args.mode)
    if bus.mode == "router":
        bus = replace(bus, mode="auto")  # the daemon's config may say router; we follow
    if args.no_multicast_scouting:
        bus = replace(bus, multicast_scouting=False)
    return bus
