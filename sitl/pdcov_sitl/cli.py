"""The ``pdcov-sitl`` console script: ``fly`` and ``replay``. Parses arguments only; bad
input prints one line naming what is wrong and exits with status 2."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from . import __version__
from .messages import GIMBAL_MODES, GNSS_ACCURACY_M, GNSS_ACCURACY_RANGE_M, GimbalMode


class UsageError(Exception):
    """Bad input on the command line or in a file it names; exit status 2."""


def build_parser() -> argparse.ArgumentParser:
    from . import replay

    parser = argparse.ArgumentParser(
        prog="pdcov-sitl", description="A JSBSim quadcopter that flies pdcov plans and "
                                       "speaks MAVLink like a real autopilot.")
    parser.add_argument("--version", action="version", version=f"pdcov-sitl {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    f = sub.add_parser("fly", help="fly a plan, sending MAVLink; write flight.tlog and "
                                   "truth.csv", description="Fly a plan from take-off to "
                       "landing while sending MAVLink like an ArduPilot or PX4 autopilot.")
    f.add_argument("--config", required=True, type=Path, help="mission config YAML")
    f.add_argument("--plan", type=Path, help="QGC .plan or WPL 110 file (as `pdcov plan` "
                                             "writes); not needed with --wait-mission")
    f.add_argument("--out", required=True, type=Path, help="folder for flight.tlog, truth.csv")
    f.add_argument("--connect", default="udpout:127.0.0.1:14550", metavar="URL",
                   help="udpout:HOST:PORT (default udpout:127.0.0.1:14550), udpin:HOST:PORT, "
                        "tcp:HOST:PORT (server), tcpin:HOST:PORT, pty: (serial pseudo-"
                        "terminal)")
    f.add_argument("--speed", type=float, default=1.0, metavar="N",
                   help="1 real time (default), N times faster, 0 as fast as possible")
    f.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    f.add_argument("--gimbal", choices=GIMBAL_MODES,
                   help="gimbal and what it reports (default: fixed for a fixed mount in the "
                        "config, ardupilot-servo for attitude_frame body, else "
                        "ardupilot-device)")
    f.add_argument("--gimbal-axes", type=int, choices=(2, 3), default=3,
                   help="stabilised gimbal axes (2: no yaw motor)")
    f.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot")
    f.add_argument("--system-id", type=int,
                   help="MAVLink system id (default: the config's log.system_id, else 1)")
    f.add_argument("--faults", metavar="SPEC", help="faults to inject (docs/simulator.md)")
    f.add_argument("--wind-mps", type=float, default=0.0,
                   help="steady wind and MIL-spec turbulence of this speed (default 0)")
    f.add_argument("--wind-from-deg", type=float, default=270.0,
                   help="direction the wind comes from, clockwise from north (default 270)")
    f.add_argument("--wait-mission", action="store_true",
                   help="wait on the ground for a mission uploaded over MAVLink")
    f.add_argument("--camera-trigger", action="store_true",
                   help="send CAMERA_IMAGE_CAPTURED per frame (also when the config's "
                        "log.frame_source is capture)")
    f.add_argument("--rangefinder-noise-m", type=float, default=0.0, metavar="SIGMA",
                   help="1-sigma noise of the downward rangefinder over terrain, m "
                        "(default 0: exact)")
    f.add_argument("--gnss-accuracy-m", type=float, default=GNSS_ACCURACY_M, metavar="H",
                   help="1-sigma horizontal error of the GPS receiver per axis, m, which "
                        f"GPS_RAW_INT reports as h_acc (default {GNSS_ACCURACY_M:g}; the "
                        "position pdcov uses, "
                        "GLOBAL_POSITION_INT, is the truth: docs/simulator.md)")
    f.add_argument("--signing-key", metavar="HEX",
                   help="MAVLink 2 signing key, 64 hex digits: sign every message and ignore "
                        "unsigned or wrongly signed ones (as the daemon's link.signing_key)")
    t = f.add_argument_group("people and the simulated detector (docs/simulator.md)")
    t.add_argument("--targets", metavar="N|FILE",
                   help="place N people in the domain's free space (seeded by --seed), or "
                        "read them from a CSV of x_m,y_m rows (ENU); simulate the detector "
                        "and publish its boxes on pdcov/<vehicle_id>/frames; write "
                        "targets.csv and detections.csv")
    t.add_argument("--person-height-m", type=float, default=1.7,
                   help="height of a standing person, for the box (default 1.7)")
    t.add_argument("--person-width-m", type=float, default=0.5,
                   help="width of a person, for the box (default 0.5)")
    t.add_argument("--box-noise-px", type=float, default=1.0, metavar="SIGMA",
                   help="1-sigma pixel noise of a box's ground point per axis (default 1)")
    t.add_argument("--look-interval-s", type=float, metavar="S",
                   help="seconds between independent detector draws for one person or cell "
                        "(default: the config's coverage.min_revisit_s; 0: every frame)")
    t.add_argument("--zenoh-connect", action="append", metavar="ENDPOINT",
                   help="Zenoh endpoint to publish the boxes through, in place of the "
                        "config's bus.connect (repeatable), e.g. tcp/127.0.0.1:7447")
    f.set_defaults(func=run_fly)
    r = sub.add_parser("replay", help="send a recorded tlog over a link",
                       description="Send a recorded tlog over a link at its pace or faster.")
    replay.add_arguments(r)
    r.set_defaults(func=replay.main)
    return parser


def _default_gimbal(mount: object) -> GimbalMode:
    from pdcov.core.pose import FixedMount

    if isinstance(mount, FixedMount):
        return "fixed"
    return "ardupilot-servo" if getattr(mount, "attitude_frame", "") == "body" \
        else "ardupilot-device"


def run_fly(args: argparse.Namespace) -> int:
    from pdcov.config.load import load_mission
    from pdcov.errors import PdcovError
    from pdcov.extras import SITL
    from pdcov.ids import valid_system_id

    from .faults import FaultSpec, FaultSpecError
    from .fly import FlyOptions, fly
    from .link import LinkError
    from .messages import Rangefinder

    if not args.speed >= 0:
        raise UsageError(f"--speed {args.speed}: expected a number >= 0")
    if args.plan is None and not args.wait_mission:
        raise UsageError("--plan: required unless --wait-mission")
    if not (args.wind_mps >= 0 and args.wind_mps < 30):
        raise UsageError(f"--wind-mps {args.wind_mps}: expected 0 <= W < 30 m/s")
    if not 0 <= args.rangefinder_noise_m < 10:
        raise UsageError(f"--rangefinder-noise-m {args.rangefinder_noise_m}: expected "
                         "0 <= SIGMA < 10 m")
    lo, hi = GNSS_ACCURACY_RANGE_M
    if not lo <= args.gnss_accuracy_m <= hi:
        raise UsageError(f"--gnss-accuracy-m {args.gnss_accuracy_m}: expected "
                         f"{lo:g} <= H <= {hi:g} m")
    key = None
    if args.signing_key is not None:
        try:
            key = bytes.fromhex(args.signing_key)
        except ValueError:
            key = b""
        if len(key) != 32:
            raise UsageError("--signing-key: expected 64 hex digits (32 bytes)")
    try:
        SITL.require()
        mission = load_mission(args.config)
        faults = FaultSpec.parse(args.faults) if args.faults else None
        system_id = args.system_id or mission.system_id or 1
        if not valid_system_id(system_id):
            raise UsageError(f"--system-id {system_id}: expected 1..255")
        people = _people(args, mission)
        opts = FlyOptions(mission=mission, plan_path=args.plan, out_dir=args.out,
                          connect=args.connect, speed=args.speed, seed=args.seed,
                          gimbal_mode=args.gimbal or _default_gimbal(mission.first_camera.mount),
                          gimbal_axes=args.gimbal_axes, faults=faults,
                          wind_mps=args.wind_mps, wind_from_deg=args.wind_from_deg,
                          autopilot=args.autopilot, system_id=system_id,
                          wait_mission=args.wait_mission, camera_trigger=args.camera_trigger,
                          signing_key=key, ground=mission.dem,
                          rangefinder=Rangefinder(noise_m=args.rangefinder_noise_m),
                          gnss_accuracy_m=args.gnss_accuracy_m, people=people)
        result = fly(opts)
    except (PdcovError, FaultSpecError, LinkError) as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"{exc.filename or ''}: {exc.strerror or exc}") from None
    print(f"flew {result.sim_s:.1f} s in {result.wall_s:.1f} s; {result.messages} messages; "
          f"{result.frames} camera frames; wrote {result.tlog} and {result.truth}")
    if people is not None:
        print(f"{len(people.targets)} people; the simulated detector reported {result.boxes} "
              f"boxes; wrote {args.out / 'targets.csv'} and {args.out / 'detections.csv'}")
    return 0


def _people(args: argparse.Namespace, mission):  # -> fly.People | None
    """--targets and the detector's options, checked; None without --targets."""
    from pdcov.bus.session import bus_config_from_dict

    from .detector import DetectorOptions
    from .fly import People
    from .targets import MAX_TARGETS, place_targets, read_targets

    if args.targets is None:
        return None
    interval = mission.min_revisit_s if args.look_interval_s is None else args.look_interval_s
    try:
        options = DetectorOptions(args.person_height_m, args.person_width_m,
                                  args.box_noise_px, interval)
    except ValueError as exc:  # "field value: expected ...": name the option
        field, rest = str(exc).split(" ", 1)
        raise UsageError(f"--{field.replace('_', '-')} {rest}") from None
    if args.targets.isdigit():
        n = int(args.targets)
        if not 1 <= n <= MAX_TARGETS:
            raise UsageError(f"--targets {n}: expected 1..{MAX_TARGETS} people or a CSV file")
        targets = place_targets(n, mission.domain, mission.terrain, args.seed)
    else:
        targets = read_targets(Path(args.targets), mission.terrain)
    bus = bus_config_from_dict(mission.raw.get("bus"), mission.source)
    if args.zenoh_connect:
        bus = bus.with_endpoints(tuple(args.zenoh_connect), None)
    return People(targets, options, bus)


def main(argv: Sequence[str] | None = None) -> int:
    os.environ.setdefault("MAVLINK20", "1")
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except UsageError as exc:
        print(f"pdcov-sitl {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
