"""``pdcov mount-check``: read the gimbal mount's parameters from the live autopilot and say
which reading of its attitude reports is in force (docs/autopilots.md, "Live: reading the
mount parameters")."""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

from pdcov.commands.args import mavlink_url
from pdcov.commands.mission_file import load_mission_warned
from pdcov.core.mount import GimbalMount
from pdcov.errors import ConfigError, where
from pdcov.telemetry.gimbal import mount_type_param, resolve_interpretation
from pdcov.telemetry.link_params import ParamRead, read_mount_params, wait_autopilot
from pdcov.telemetry.upload import mavlink2_connection

PARAMS_ORIGIN = "the autopilot's parameters over MAVLink"
GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = 190  # MAV_COMP_ID_MISSIONPLANNER, as ground stations introduce themselves

# ArduPilot MNTn_TYPE values (AP_Mount_Params.cpp @Values), for the report only.
MOUNT_TYPE_NAMES = {0: "None", 1: "Servo", 2: "3DR Solo", 3: "Alexmos Serial",
                    4: "SToRM32 MAVLink", 5: "SToRM32 Serial", 6: "Gremsy", 7: "BrushlessPWM",
                    8: "Siyi", 9: "Scripting", 10: "Xacti", 11: "Viewpro", 12: "Topotek",
                    13: "CADDX"}


def _positive_s(text: str) -> float:
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected seconds > 0, got {text!r}")
    return value


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "mount-check", help="read the gimbal mount's parameters from the autopilot",
        description="Connect to the autopilot, read its mount type and angle limits "
                    "(MNTn_TYPE, MNTn_*_MIN/MAX; MNT_TYPE, MNT_ANGMIN/ANGMAX_* on ArduPilot "
                    "4.2 and older: the list pdcov serve asks for too) with "
                    "PARAM_REQUEST_READ, and say which reading of the gimbal's attitude "
                    "reports the config's mount puts in force, and why.")
    p.add_argument("--config", required=True, type=Path, help="mission config YAML")
    p.add_argument("--connect", required=True, metavar="URL", type=mavlink_url,
                   help="MAVLink link as pymavlink opens it: udpin:127.0.0.1:14550, "
                        "udpout:HOST:PORT, tcp:HOST:PORT or a serial device")
    p.add_argument("--timeout-s", type=_positive_s, default=5.0,
                   help="wait for the autopilot's HEARTBEAT, and for each read of the "
                        "parameters, at most this long (5)")
    p.set_defaults(func=run_mount_check)


def run_mount_check(args: argparse.Namespace) -> int:
    mission = load_mission_warned(args.config, "mount-check")
    mount = mission.first_camera.mount
    if not isinstance(mount, GimbalMount):
        raise ConfigError(f"{where(mission.source, 'mount.type')}: mount-check reads a gimbal "
                          f"mount's parameters; this mount is fixed (set type: gimbal)")
    conn = mavlink2_connection(args.connect, GCS_SYSTEM_ID, GCS_COMPONENT_ID)
    try:
        system, component = wait_autopilot(conn, args.timeout_s, system_id=mission.system_id)
        read = read_mount_params(conn, mount.instance, target_system=system,
                                 target_component=component, timeout_s=args.timeout_s)
    finally:
        conn.close()
    print(f"autopilot: system {system}, component {component} on {args.connect}")
    print(mount_report(mount, read))
    return 0


def mount_report(mount: GimbalMount, read: ParamRead) -> str:
    """What was read, what is missing, and the interpretation in force with its reason."""
    def shown(name: str) -> str:
        value = read.values[name]
        kind = MOUNT_TYPE_NAMES.get(int(value)) if name.endswith("_TYPE") else None
        return f"{name}={value:g}" + (f" ({kind})" if kind else "")

    lines = ["parameters read: " + (", ".join(shown(n) for n in read.requested
                                               if n in read.values) or "none"),
             "missing (no reply): " + (", ".join(read.missing) or "none")]
    interp = resolve_interpretation(mount, read.values, PARAMS_ORIGIN)
    lines.append(f"interpretation: {interp.frame}: {interp.describe()}")
    found = mount_type_param(read.values, mount.instance)
    if found is not None and found[1] == 0:
        lines.append(f"warning: {found[0]}=0: the autopilot has no mount {mount.instance} "
                     f"(check mount.instance and the autopilot's MNT*_TYPE)")
    elif found is not None and mount.attitude_frame != "auto":
        auto = resolve_interpretation(dataclasses.replace(mount, attitude_frame="auto"),
                                      read.values, PARAMS_ORIGIN)
        if auto.frame != interp.frame:
            lines.append(f"warning: {found[0]}={found[1]} reads as {auto.frame!r} under "
                         f"attitude_frame: auto; the configured {interp.frame!r} is in force")
    return "\n".join(lines)
