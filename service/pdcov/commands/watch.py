"""``pdcov watch``: follow one vehicle or the fleet over Zenoh (terminal, web map, record)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING

from pdcov.commands.bus_args import add_bus_args, bus_of
from pdcov.errors import ConfigError
from pdcov.extras import COT, GROUND
from pdcov.ids import VEHICLE_ID_RULE, valid_vehicle_id

if TYPE_CHECKING:
    from pdcov.ground.web import PlanLayer


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "watch", help="follow the vehicles' coverage live (terminal, web map)",
        description="Subscribe over Zenoh to the daemons (`pdcov serve`) of one vehicle or "
                    "every vehicle, rebuild their grids exactly (snapshot, then tiles) and "
                    "show the coverage: per vehicle and merged for the fleet "
                    "(docs/ground-station.md).")
    p.add_argument("--vehicle", default="all", metavar="ID",
                   help="vehicle id to follow, or 'all' (default)")
    p.add_argument("--config", type=Path,
                   help="mission config YAML: its bus section (mode, endpoints, TLS) and "
                        "domain (drawn on the web map, report figures with --record)")
    add_bus_args(p)
    p.add_argument("--web", metavar="HOST:PORT",
                   help="serve the live map, e.g. 127.0.0.1:8080, to whoever has its access "
                        "token: the address to open, token included, is printed at start")
    p.add_argument("--web-token-file", type=Path, metavar="PATH",
                   help="read the web map's token from PATH (chmod 600; at least 16 "
                        "characters A-Z a-z 0-9 _ . ~ -) instead of making a new one at each "
                        "start; also from the environment variable PDCOV_WEB_TOKEN, never "
                        "from the command line (which other users see in ps)")
    p.add_argument("--web-operator-token-file", type=Path, metavar="PATH",
                   help="the operator's token (chmod 600, another than the view token's): "
                        "only a page opened with it may re-task; without it no one commands "
                        "from the web map")
    p.add_argument("--web-allow-host", action="append", metavar="NAME",
                   help="a host name the web map answers to (repeatable), e.g. the name a "
                        "reverse proxy forwards; IP addresses, localhost and this machine's "
                        "name always are, other names are refused (DNS rebinding)")
    p.add_argument("--basemap", type=Path, metavar="PATH",
                   help="offline basemap under the web map: a folder of XYZ tiles "
                        "({z}/{x}/{y}.png or .jpg) or an .mbtiles file")
    p.add_argument("--plan", action="append", type=Path, metavar="FILE",
                   help="a mission file (.plan or QGC WPL 110) whose waypoints the web map "
                        "draws (repeatable)")
    p.add_argument("--record", type=Path, metavar="DIR",
                   help="write what is received, the exports for CalTopo, Google Earth and "
                        "ATAK (DIR/exports/, kept current), and at the end the grids and the "
                        "report")
    p.add_argument("--cot", metavar="URL",
                   help="send the aircraft (with its camera's field of view) and the "
                        "detection candidates as Cursor-on-Target to URL: udp://HOST:PORT "
                        "(ATAK's mesh group udp://239.2.3.1:6969), tcp://HOST:PORT (a TAK "
                        "server's streaming input) or tls://HOST:PORT (its TLS input, "
                        "mutual TLS: --cot-cert and --cot-ca)")
    p.add_argument("--cot-cert", type=Path, metavar="FILE",
                   help="with --cot tls://: the client certificate the TAK server issued, "
                        "PEM (the key in it or in --cot-key) or PKCS#12 (.p12, its "
                        "password in --cot-key-password-file)")
    p.add_argument("--cot-key", type=Path, metavar="PEM",
                   help="with --cot tls://: the client certificate's private key, PEM")
    p.add_argument("--cot-key-password-file", type=Path, metavar="PATH",
                   help="with --cot tls://: the password of the encrypted key or .p12 "
                        "(chmod 600; never on the command line, which ps shows)")
    p.add_argument("--cot-ca", type=Path, metavar="PEM",
                   help="with --cot tls://: the CA that signed the TAK server's "
                        "certificate; the server is always verified against it")
    p.add_argument("--cot-server-name", metavar="NAME",
                   help="with --cot tls://: the host name the server's certificate "
                        "carries, when it is not the one in the URL (e.g. an IP address "
                        "dialled)")
    p.add_argument("--once", action="store_true",
                   help="print one report when the grids are in (or after --wait-s) and exit")
    p.add_argument("--wait-s", type=float, default=10.0,
                   help="with --once: longest wait for the vehicles (default 10 s)")
    p.add_argument("--refly", metavar="VEHICLE",
                   help="propose a re-fly of the merged grid's gaps to VEHICLE (needs "
                        "--config), show it, ask for confirmation and send it to the "
                        "vehicle's daemon, which uploads it to the autopilot; exits 0 once "
                        "the autopilot accepted it (docs/ground-station.md \"Re-tasking\")")
    p.add_argument("--target-pd", type=float, metavar="P",
                   help="with --refly and the web map: the P_D every free cell should reach "
                        "(default: the mission's largest threshold)")
    p.add_argument("--operator-key", type=Path, metavar="KEYFILE",
                   help="with --refly and the web map: the operator key that signs re-flies "
                        "(operator.key of `pdcov keys new`; without it none is sent)")
    p.add_argument("--yes", action="store_true",
                   help="with --refly: send without asking (scripts)")
    p.add_argument("--plain", action="store_true",
                   help="print a line when the coverage changes instead of the live table "
                        "(the default when the output is not a terminal)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    GROUND.require()
    from pdcov.commands.mission_file import load_mission_warned
    from pdcov.ground.app import WatchOptions, parse_web_address, run_watch, stdout_is_terminal

    vehicle = None if args.vehicle == "all" else args.vehicle
    if vehicle is not None and not valid_vehicle_id(vehicle):
        raise ConfigError(f"--vehicle {args.vehicle!r}: expected {VEHICLE_ID_RULE}, or 'all'")
    mission = load_mission_warned(args.config, "watch") if args.config else None
    bus = bus_of(args, mission)
    web = parse_web_address(args.web) if args.web else None
    access = None
    if web is not None:
        import os
        import socket

        from pdcov.ground.web_auth import web_access

        access = web_access(web[0], args.web_token_file, args.web_allow_host or (),
                            os.environ, socket.gethostname(), args.web_operator_token_file)
    elif args.web_token_file is not None or args.web_operator_token_file is not None \
            or args.web_allow_host or args.basemap is not None or args.plan:
        raise ConfigError("--web-token-file, --web-operator-token-file, --web-allow-host, "
                          "--basemap and --plan go with --web HOST:PORT")
    if args.cot is not None:
        from pdcov.ground.cot_feed import parse_cot_url

        COT.require()
        parse_cot_url(args.cot)
    from pdcov.ground.cot_tls import CotTlsFiles, cot_tls_of

    cot_tls = cot_tls_of(args.cot, CotTlsFiles(
        args.cot_cert, args.cot_key, args.cot_key_password_file, args.cot_ca,
        args.cot_server_name), time.time())
    if not args.wait_s > 0:
        raise ConfigError(f"--wait-s {args.wait_s}: expected seconds > 0")
    from pdcov.planning.refly import ReflySettings
    from pdcov.service.memory_budget import memory_limit_bytes

    if args.refly is not None and not valid_vehicle_id(args.refly):
        raise ConfigError(f"--refly {args.refly!r}: expected a vehicle id ({VEHICLE_ID_RULE})")
    if (args.refly or args.target_pd is not None or args.yes) and mission is None:
        raise ConfigError("--refly, --target-pd and --yes need --config: the mission flown")
    if args.yes and args.refly is None:
        raise ConfigError("--yes goes with --refly VEHICLE")
    settings = None
    if mission is not None:
        settings = ReflySettings(args.target_pd if args.target_pd is not None
                                 else max(mission.thresholds))
    operator_key = None
    if args.operator_key is not None:
        from pdcov.bus.operator_keys import load_private_key

        operator_key = load_private_key(args.operator_key)
    plans: tuple[PlanLayer, ...] = ()
    basemap = None
    if web is not None:
        from pdcov.ground.basemap import open_basemap
        from pdcov.ground.web import plan_layer

        plans = tuple(plan_layer(p) for p in args.plan or ())
        basemap = None if args.basemap is None else open_basemap(args.basemap)
    return run_watch(WatchOptions(
        bus=bus, vehicle=vehicle, mission=mission, web=web, web_access=access,
        basemap=basemap, plans=plans,
        record=args.record, once=args.once, wait_s=args.wait_s, cot=args.cot, cot_tls=cot_tls,
        plain=args.plain or not stdout_is_terminal(), refly=args.refly,
        refly_settings=settings, yes=args.yes, operator_key=operator_key,
        memory_limit=memory_limit_bytes()))
