"""``pdcov plan``: a coverage plan and its predicted P_D (the choice of parameters:
commands/optimise.py; the follow-up flight over the gaps: commands/refly.py; the vantage
pattern: commands/plan_vantage.py; the upload: commands/upload.py).

Algorithms, limits and file formats: docs/planning.md. The mission config's optional
``planning`` section sets the vehicle's kinematic limits for the predictions:
``{max_accel_mps2: 2.5, max_yaw_rate_deg_s: 60, tilt: true, corner_cut_m: 2,
gimbal_rate_deg_s: 90, gimbal_pitch_deg: -90}``, and how plans meet the mission's terrain:
``{terrain_frame: amsl, terrain_tolerance_m: 2, terrain_max_climb_mps: 2.5,
terrain_max_descent_mps: 1.5, terrain_clearance_m: 10}`` (``--terrain-*`` flags override them).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from pdcov.atomic import replacing_dir
from pdcov.commands.args import finite, output_dir, positive
from pdcov.commands.mission_file import load_mission_warned
from pdcov.commands.plan_args import (
    firmware_args,
    planning_overrides,
    side_overlap,
    spacing_args,
    terrain_args,
)
from pdcov.commands.plan_output import replaced_note, terrain_warnings, write_prediction
from pdcov.commands.plan_vantage import VANTAGE_FLAGS, run_plan_vantage, vantage_args
from pdcov.errors import ConfigError
from pdcov.planning.optimise import (
    PATTERN_OPTIONS,
    PATTERNS,
    PlanParams,
    build_plan,
    predict,
    refuse_options,
)
from pdcov.planning.patterns import track_spacing_m
from pdcov.planning.scenario import check_plan_size, scenario_of


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("plan", help="make a coverage plan and predict its P_D map",
                              description="Write a plan (.plan and .waypoints) and the "
                                          "predicted evaluation of flying it.")
    p.add_argument("--config", required=True, type=Path, help="mission config YAML")
    p.add_argument("--pattern", choices=PATTERNS, default="lawnmower",
                   help="coverage pattern (docs/planning.md)")
    p.add_argument("--altitude-m", type=positive,
                   help="altitude above ground (required, but for vantage: --altitudes-m)")
    spacing_args(p)
    p.add_argument("--heading-deg", type=finite,
                   help="track direction (lawnmower) or first leg, deg clockwise from "
                        "north (default 0)")
    p.add_argument("--speed-mps", type=positive, default=5.0, help="ground speed, m/s")
    p.add_argument("--centre-enu-m", type=finite, nargs=2, metavar=("X", "Y"),
                   help="spiral centre or IAMSAR datum in ENU m, inside the domain "
                        "(default: docs/planning.md)")
    p.add_argument("--radius-m", type=positive, help="sector search radius (default: the "
                                                  "largest keeping the triangles inside)")
    p.add_argument("--zoom-hfov-deg", type=positive, metavar="DEG",
                   help="zoom the camera to this horizontal field of view for the whole plan "
                        "(a MAV_CMD_SET_CAMERA_ZOOM item before the first waypoint; needs "
                        "camera.zoom fov_status; vantage: --zooms-hfov-deg)")
    p.add_argument("--out", required=True, type=output_dir, help="folder to write")
    p.add_argument("--no-figures", action="store_true", help="skip heatmap/threshold PNGs")
    terrain_args(p)
    firmware_args(p)
    vantage_args(p)
    p.set_defaults(func=run_plan)


def run_plan(args: argparse.Namespace) -> int:
    given = [("spacing", "--spacing-m", args.spacing_m), ("spacing", "--overlap", args.overlap),
             ("heading", "--heading-deg", args.heading_deg),
             ("centre", "--centre-enu-m", args.centre_enu_m),
             ("radius", "--radius-m", args.radius_m)]
    given += [("vantage", "--" + k.replace("_", "-"), getattr(args, k)) for k in VANTAGE_FLAGS]
    refuse_options(args.pattern, {name: flag for name, flag, value in given
                                  if value is not None})
    if args.pattern == "vantage":
        return run_plan_vantage(args)
    if args.altitude_m is None:
        raise ConfigError(f"--altitude-m is required for the {args.pattern} pattern")
    mission = load_mission_warned(args.config, "plan")
    sc = scenario_of(mission, planning_overrides(args))
    params = PlanParams(args.pattern, args.altitude_m, args.speed_mps,
                        math.radians(args.heading_deg or 0.0), args.spacing_m,
                        side_overlap(args),
                        tuple(args.centre_enu_m) if args.centre_enu_m else None, args.radius_m,
                        args.zoom_hfov_deg)
    if "spacing" in PATTERN_OPTIONS[args.pattern]:
        spacing_m = args.spacing_m or track_spacing_m(
            sc.swath_width_m(args.altitude_m, zoom_hfov_deg=args.zoom_hfov_deg), side_overlap(args))
        check_plan_size(sc, spacing_m, args.speed_mps)
    plan, spacing = build_plan(sc, params)
    pred = predict(sc, plan, params, progress=True)
    with replacing_dir(args.out) as replaced:
        summary = write_prediction(
            args.out, mission, pred, pred.grid,
            f"predicted: {plan.description} at {args.altitude_m:g} m",
            spacing if "spacing" in PATTERN_OPTIONS[args.pattern] else None,
            figures=not args.no_figures, terrain_warnings=terrain_warnings(sc, pred),
            firmware=args.firmware)
    print(summary + replaced_note(replaced, args.out))
    return 0
