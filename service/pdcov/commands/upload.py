"""``pdcov upload``: a prepared plan (.plan or WPL from ``pdcov plan``) to a vehicle, over
a MAVLink link (``--connect``) or, signed, through the bus to its daemon (``--bus``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pdcov.commands.args import mavlink_url, positive
from pdcov.commands.bus_args import add_bus_args, bus_of
from pdcov.errors import ConfigError
from pdcov.ids import VEHICLE_ID_RULE, valid_vehicle_id


def register(sub: argparse._SubParsersAction) -> None:
    u = sub.add_parser("upload", help="upload a plan to a vehicle (MAVLink, or the bus)",
                       description="Upload a .plan or WPL file with the MAVLink mission "
                                   "protocol (--connect), or send it signed to a vehicle's "
                                   "daemon through the bus (--bus), and report what the "
                                   "vehicle said.")
    u.add_argument("plan", type=Path, nargs="?", help=".plan or WPL 110 file")
    u.add_argument("--plan", type=Path, dest="plan_opt", metavar="FILE",
                   help="the plan file (instead of the positional argument)")
    how = u.add_mutually_exclusive_group(required=True)
    how.add_argument("--connect", type=mavlink_url,
                     help="pymavlink URL, e.g. udpin:0.0.0.0:14550, tcp:127.0.0.1:5760, "
                          "/dev/ttyUSB0")
    how.add_argument("--bus", metavar="VEHICLE",
                     help="send to VEHICLE's daemon over Zenoh (needs --operator-key and "
                          "--config: the mission whose bounds the vehicle enforces)")
    u.add_argument("--operator-key", type=Path, metavar="KEYFILE",
                   help="with --bus: the operator key that signs (`pdcov keys new`)")
    u.add_argument("--config", type=Path, help="with --bus: the mission config (bus "
                   "section, domain and service.retask_limits)")
    add_bus_args(u)
    u.add_argument("--timeout-s", type=positive, default=10.0,
                   help="wait this long for the vehicle's heartbeat (--connect), or for "
                        "the daemon's answer after the autopilot's (--bus: plus 30 s), s")
    u.set_defaults(func=run_upload)


def run_upload(args: argparse.Namespace) -> int:
    from pdcov.planning.plan_files import read_mission

    path = args.plan_opt or args.plan
    if path is None or (args.plan_opt and args.plan):
        raise ConfigError("give the plan file once: PLAN or --plan FILE")
    mission = read_mission(path)
    if args.bus is not None:
        return _upload_bus(args, path, mission.items)
    from pdcov.core.mission import MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL, MissionItem
    from pdcov.telemetry.upload import upload_mission

    home = mission.home
    if home is None:
        first = next((i for i in mission.items if i.command == MAV_CMD_NAV_WAYPOINT), None)
        if first is None:
            raise ConfigError(f"{path}: no waypoint to upload")
        home = MissionItem(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL, lat_deg=first.lat_deg,
                           lon_deg=first.lon_deg)
    result = upload_mission(mission.items, args.connect, home, timeout_s=args.timeout_s)
    print(result.report(), file=sys.stdout if result.accepted else sys.stderr)
    return 0 if result.accepted else 1


def _upload_bus(args: argparse.Namespace, path: Path, items: tuple) -> int:
    import secrets
    import time

    from pdcov.bus.operator_keys import load_private_key
    from pdcov.bus.retask import plan_hash
    from pdcov.commands.mission_file import load_mission_warned
    from pdcov.ground.bus_upload import send_retask
    from pdcov.ground.retask import RetaskNotSent, signed_request

    if not valid_vehicle_id(args.bus):
        raise ConfigError(f"--bus {args.bus!r}: expected a vehicle id ({VEHICLE_ID_RULE})")
    if args.config is None:
        raise ConfigError("--bus needs --config: the mission flown (its domain and "
                          "service.retask_limits are the bounds the vehicle enforces)")
    mission = load_mission_warned(args.config, "upload")
    key = load_private_key(args.operator_key) if args.operator_key else None
    try:
        payload = signed_request(key, args.bus, tuple(items), f"{path.name}", mission,
                                 mission.origin(), time.time(), secrets.token_hex(16))
    except RetaskNotSent as exc:
        print(f"pdcov upload: {exc}", file=sys.stderr)
        return 1
    print(f"sending mission {plan_hash(items)} ({len(items)} items) to {args.bus}, signed "
          f"by key {key.id if key else ''} ...", flush=True)
    accepted, line = send_retask(bus_of(args, mission), args.bus, payload,
                                 args.timeout_s + 30.0).verdict()
    print(f"{args.bus} mission {plan_hash(items)}: {line}",
          file=sys.stdout if accepted else sys.stderr)
    return 0 if accepted else 1
