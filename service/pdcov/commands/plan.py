"""``pdcov plan | optimise | refly``: coverage plans, their predicted P_D, the choice
of parameters and the follow-up flight over the gaps (the upload: commands/upload.py).

Algorithms, limits and file formats: docs/planning.md. The mission config's optional
``planning`` section sets the vehicle's kinematic limits for the predictions:
``{max_accel_mps2: 2.5, max_yaw_rate_deg_s: 60, tilt: true, corner_cut_m: 2,
gimbal_rate_deg_s: 90, gimbal_pitch_deg: -90}``, and how plans meet the mission's terrain:
``{terrain_frame: amsl, terrain_tolerance_m: 2, terrain_max_climb_mps: 2.5,
terrain_max_descent_mps: 1.5, terrain_clearance_m: 10}`` (``--terrain-*`` flags override them).
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.atomic import atomic_write, replacing_dir, write_text_atomic
from pdcov.commands.args import (
    finite,
    nonnegative,
    output_dir,
    overlap,
    positive,
    positive_int,
    probability,
)
from pdcov.commands.mission_file import load_mission_warned
from pdcov.config.mission import Mission
from pdcov.core.blur import describe_blur
from pdcov.core.grid import CoverageGrid
from pdcov.core.mission import (
    AltitudeFrame,
    GimbalCommand,
    HoverItem,
)
from pdcov.errors import ConfigError
from pdcov.extras import ROUTING
from pdcov.planning.cover import Cover
from pdcov.planning.optimise import (
    PATTERN_OPTIONS,
    PATTERNS,
    PlanParams,
    Prediction,
    Scenario,
    Score,
    best_index,
    build_plan,
    candidates,
    pareto_front,
    predict,
    refuse_options,
    sweep,
    with_spacing,
)
from pdcov.planning.patterns import track_spacing_m
from pdcov.planning.plan import GimbalPointing, write_plan
from pdcov.planning.refly import ReflySettings, refly_of_grid
from pdcov.planning.scenario import check_plan_size, scenario_of
from pdcov.planning.terrain_follow import (
    clearance_intrusions,
    steep_legs,
)
from pdcov.planning.tours import Fleet
from pdcov.planning.vantage import CoverObjective, VantageSettings, is_nadir
from pdcov.planning.vantage_missions import (
    VantageMissions,
    plan_vantage_missions,
    vantage_score,
)
from pdcov.report.outputs import summary_text, write_outputs


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("plan", help="make a coverage plan and predict its P_D map",
                              description="Write a plan (.plan and .waypoints) and the "
                                          "predicted evaluation of flying it.")
    p.add_argument("--config", required=True, type=Path, help="mission config YAML")
    p.add_argument("--pattern", choices=PATTERNS, default="lawnmower",
                   help="coverage pattern (docs/planning.md)")
    p.add_argument("--altitude-m", type=positive,
                   help="altitude above ground (required, but for vantage: --altitudes-m)")
    _spacing_args(p)
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
    _terrain_args(p)
    _vantage_args(p)
    p.set_defaults(func=run_plan)

    o = subparsers.add_parser(
        "optimise", help="sweep plan parameters; Pareto front of P_D coverage vs flight time",
        description="Predict every combination of the given parameters on all cores and "
                    "report the plans on the Pareto front of the proportion of cells at or "
                    "above the target P_D against flight time.")
    o.add_argument("--config", required=True, type=Path, help="mission config YAML")
    o.add_argument("--target-pd", type=probability, required=True, help="P_D target per cell")
    o.add_argument("--min-proportion", type=probability, default=0.95,
                   help="proportion of cells that must reach the target (0.95); the best "
                        "plan is the shortest flight reaching it")
    o.add_argument("--patterns", nargs="+", choices=PATTERNS, default=["lawnmower", "spiral"],
                   help="patterns to try (vantage: planned for --target-pd on "
                        "--min-proportion of the cells at each altitude and speed)")
    o.add_argument("--altitudes-m", nargs="+", type=positive, default=[8.0, 10.0, 12.0],
                   help="altitudes above ground to try, m")
    o.add_argument("--speeds-mps", nargs="+", type=positive, default=[3.0, 5.0],
                   help="ground speeds to try, m/s")
    o.add_argument("--headings-deg", nargs="+", type=finite, default=[0.0, 90.0],
                   help="track directions to try, deg clockwise from north")
    o.add_argument("--spacings-m", nargs="+", type=positive,
                   help="track spacings (default: from the swath and --overlaps)")
    o.add_argument("--overlaps", nargs="+", type=overlap, default=[0.0, 0.2, 0.4],
                   help="side overlaps of the swath to try")
    o.add_argument("--zooms-hfov-deg", nargs="+", type=positive, metavar="DEG",
                   help="camera zooms to try with each altitude, as horizontal fields of view "
                        "(deg; needs camera.zoom fov_status; default: not zoomed)")
    o.add_argument("--processes", type=positive_int, help="worker processes (default: all cores)")
    _terrain_args(o)
    o.add_argument("--out", required=True, type=output_dir, help="folder to write")
    o.set_defaults(func=run_optimise)

    r = subparsers.add_parser("refly", help="find cells below the target after a flight "
                                            "and plan a follow-up",
                              description="Gap finder and follow-up flight.")
    r.add_argument("--config", required=True, type=Path, help="mission config YAML")
    r.add_argument("--grid", required=True, type=Path, help="grid.npz of the flight so far")
    r.add_argument("--target-pd", type=probability, required=True,
                   help="P_D every free cell should reach; cells below it are gaps")
    r.add_argument("--altitude-m", type=positive, default=10.0, help="altitude above ground, m")
    r.add_argument("--speed-mps", type=positive, default=3.0, help="ground speed, m/s")
    _spacing_args(r)
    r.add_argument("--headings-deg", nargs="+", type=finite, default=[0.0, 90.0],
                   help="track directions to try, deg clockwise from north")
    r.add_argument("--start-enu-m", type=finite, nargs=2, default=[0.0, 0.0],
                   metavar=("X", "Y"), help="where the follow-up starts (home: 0 0)")
    _terrain_args(r)
    r.add_argument("--out", required=True, type=output_dir, help="folder to write")
    r.set_defaults(func=run_refly)


def _spacing_args(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--spacing-m", type=positive, help="track spacing (default: from the camera "
                                                   "swath and --overlap)")
    g.add_argument("--overlap", type=overlap, help="side overlap of the swath (default 0.2)")


def _vantage_args(p: argparse.ArgumentParser) -> None:
    """The vantage pattern's options (docs/planning.md "Vantage points")."""
    g = p.add_argument_group("vantage points (--pattern vantage)")
    g.add_argument("--target-pd", type=probability, help="P_D every required cell must reach")
    g.add_argument("--target-share", type=probability,
                   help="proportion of free cells that must reach it (default 1: all)")
    g.add_argument("--altitudes-m", nargs="+", type=positive,
                   help="candidate altitudes above ground, m (default --altitude-m, else 10)")
    g.add_argument("--hover-s", nargs="+", type=positive,
                   help="candidate hover times at a point, s (default 2)")
    g.add_argument("--lattice-m", type=positive,
                   help="spacing of the candidate points, m (default half the swath at the "
                        "lowest altitude)")
    g.add_argument("--clearance-m", type=nonnegative,
                   help="distance points and transits keep from obstacles and the domain's "
                        "edge, m (default planning.corner_cut_m, 2)")
    g.add_argument("--objective", choices=list(CoverObjective),
                   type=CoverObjective, help="minimise the number of points (default) or "
                                            "the time they take")
    g.add_argument("--ilp-time-limit-s", type=nonnegative,
                   help="time for the exact integer program (HiGHS), s (default 20; 0: "
                        "greedy only)")
    g.add_argument("--vehicles", type=positive_int, help="routes of balanced time (default 1)")
    g.add_argument("--max-flight-time-s", type=positive,
                   help="split each vehicle's route into sorties of at most this, s")
    g.add_argument("--routing-time-s", type=positive,
                   help="time for OR-Tools' route search, s (default 2)")
    g.add_argument("--gimbal-command", choices=list(GimbalCommand), type=GimbalCommand,
                   help="gimbal mission item: manager (DO_GIMBAL_MANAGER_PITCHYAW, default) "
                        "or mount (DO_MOUNT_CONTROL, older firmware: no earth-frame yaw)")
    g.add_argument("--gimbal-pitches-deg", nargs="+", type=finite, metavar="DEG",
                   help="candidate gimbal pitches, deg (-90 nadir; within the mount's "
                        "pitch_limits_deg; default planning.gimbal_pitch_deg)")
    g.add_argument("--gimbal-yaws", type=int, metavar="N",
                   help="earth-frame gimbal yaws per non-nadir pitch, 360/N deg apart from "
                        "north (YAW_LOCK; 0: the yaw follows the vehicle; default 8 with an "
                        "oblique --gimbal-pitches-deg, else 0)")
    g.add_argument("--zooms-hfov-deg", nargs="+", type=positive, metavar="DEG",
                   help="candidate camera zooms as horizontal fields of view, deg (needs "
                        "camera.zoom fov_status; include the configured camera's to keep "
                        "unzoomed candidates; default: not zoomed, no zoom item)")
    g.add_argument("--hover-item", choices=list(HoverItem), type=HoverItem,
                   help="write hovers as waypoint (NAV_WAYPOINT hold time, default) or "
                        "loiter-time (NAV_LOITER_TIME) items")


_VANTAGE_FLAGS = ("target_pd", "target_share", "altitudes_m", "hover_s", "lattice_m",
                  "clearance_m", "objective", "ilp_time_limit_s", "vehicles",
                  "max_flight_time_s", "routing_time_s", "gimbal_command",
                  "gimbal_pitches_deg", "gimbal_yaws", "hover_item", "zooms_hfov_deg")
DEFAULT_GIMBAL_YAWS = 8
"""Earth-frame yaws per oblique pitch when --gimbal-pitches-deg names one."""


def _terrain_args(p: argparse.ArgumentParser) -> None:
    """Flags overriding the planning section's terrain keys (docs/planning.md)."""
    p.add_argument("--terrain-frame", choices=list(AltitudeFrame),
                   help="over the mission's terrain: amsl (waypoints along the terrain, "
                        "MSL), terrain_alt (heights above terrain, the autopilot follows) "
                        "or relative (a constant altitude above home); default "
                        "planning.terrain_frame, else amsl with a terrain")
    p.add_argument("--terrain-tolerance-m", type=positive,
                   help="height above terrain kept within this (default "
                        "planning.terrain_tolerance_m, 2)")
    p.add_argument("--terrain-clearance-m", type=finite,
                   help="warn where terrain plus this rises into the path (default "
                        "planning.terrain_clearance_m, 10)")


def planning_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The planning keys the ``--terrain-*`` flags set."""
    given = {"terrain_frame": args.terrain_frame,
             "terrain_tolerance_m": args.terrain_tolerance_m,
             "terrain_clearance_m": args.terrain_clearance_m}
    return {k: v for k, v in given.items() if v is not None}


def _overlap(args: argparse.Namespace) -> float:
    return 0.2 if args.overlap is None else args.overlap


# At most this many terrain warnings of each kind are printed, one line each.
MAX_TERRAIN_LINES = 10


def terrain_warnings(sc: Scenario, pred: Prediction) -> list[str]:
    """One line per stretch of the predicted plan where the terrain plus the clearance rises
    into the path, then per leg of a terrain-frame plan steeper than the climb or descent
    rate (none without terrain); at most MAX_TERRAIN_LINES of each and a count."""
    if sc.terrain is None:
        return []
    lines = []
    for found in ([i.message() for i in clearance_intrusions(pred.plan, sc.terrain,
                                                             sc.following.clearance_m)],
                  steep_legs(pred.plan, sc.following)):
        lines += found[:MAX_TERRAIN_LINES]
        if len(found) > MAX_TERRAIN_LINES:
            lines.append(f"and {len(found) - MAX_TERRAIN_LINES} more like it")
    return lines


def write_prediction(out: Path, mission: Mission, pred: Prediction, grid: CoverageGrid,
                      title: str, spacing_m: float | None, figures: bool = True,
                      terrain_warnings: Sequence[str] = ()) -> str:
    """Plan files and the predicted evaluation in ``out``; returns the summary text. The
    ``terrain_warnings`` (the function of that name) go to stderr and metrics.json."""
    for line in terrain_warnings:
        print(f"WARNING: terrain: {line}", file=sys.stderr)
    out.mkdir(parents=True, exist_ok=True)
    origin = mission.origin()
    write_plan(out / "plan.plan", pred.plan, origin)
    write_plan(out / "plan.waypoints", pred.plan, origin)
    extra = {"plan": {"description": pred.plan.description,
                      "waypoints": len(pred.plan.waypoints),
                      "spacing_m": spacing_m,
                      "flight_time_s": round(pred.flight.duration_s, 2),
                      "path_length_m": round(pred.flight.path_length_m, 2),
                      "planned_path_length_m": round(pred.plan.path_length_m, 2),
                      "altitude_frame": str(pred.plan.altitude_frame),
                      "terrain_warnings": list(terrain_warnings)}}
    run = write_outputs(out, mission, grid, origin, title=title,
                        track_enu=pred.flight.r_body_enu[:, :2], plan_enu=pred.plan.xy_enu_m,
                        extra_metrics=extra, figures=figures)
    return summary_text(run, [
        f"plan: {pred.plan.description}; {len(pred.plan.waypoints)} waypoints",
        f"predicted flight time: {pred.flight.duration_s:.1f} s   path length: "
        f"{pred.flight.path_length_m:.1f} m",
        describe_blur(grid.blur_effect, grid.exposure_s, grid.frames_blurred, grid.frames),
        f"wrote plan.plan (QGroundControl) and plan.waypoints (WPL 110) in {out}"])


def run_plan(args: argparse.Namespace) -> int:
    given = [("spacing", "--spacing-m", args.spacing_m), ("spacing", "--overlap", args.overlap),
             ("heading", "--heading-deg", args.heading_deg),
             ("centre", "--centre-enu-m", args.centre_enu_m),
             ("radius", "--radius-m", args.radius_m)]
    given += [("vantage", "--" + k.replace("_", "-"), getattr(args, k)) for k in _VANTAGE_FLAGS]
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
                        _overlap(args),
                        tuple(args.centre_enu_m) if args.centre_enu_m else None, args.radius_m,
                        args.zoom_hfov_deg)
    if "spacing" in PATTERN_OPTIONS[args.pattern]:
        spacing_m = args.spacing_m or track_spacing_m(
            sc.swath_width_m(args.altitude_m, zoom_hfov_deg=args.zoom_hfov_deg), _overlap(args))
        check_plan_size(sc, spacing_m, args.speed_mps)
    plan, spacing = build_plan(sc, params)
    pred = predict(sc, plan, params, progress=True)
    with replacing_dir(args.out) as replaced:
        summary = write_prediction(
            args.out, mission, pred, pred.grid,
            f"predicted: {plan.description} at {args.altitude_m:g} m",
            spacing if "spacing" in PATTERN_OPTIONS[args.pattern] else None,
            figures=not args.no_figures, terrain_warnings=terrain_warnings(sc, pred))
    print(summary + _replaced_note(replaced, args.out))
    return 0


def vantage_settings(args: argparse.Namespace, target_pd: float, target_share: float,
                     alts_m: Sequence[float], speed_mps: float) -> VantageSettings:
    """The vantage options of ``pdcov plan`` (their defaults where not given)."""
    pitches = args.gimbal_pitches_deg
    yaws = args.gimbal_yaws
    if yaws is None:
        yaws = DEFAULT_GIMBAL_YAWS if pitches and not all(map(is_nadir, pitches)) else 0
    return VantageSettings(
        target_pd, tuple(alts_m), tuple(args.hover_s or (2.0,)), target_share,
        args.lattice_m, args.clearance_m, speed_mps,
        args.objective or CoverObjective.POINTS,
        20.0 if args.ilp_time_limit_s is None else args.ilp_time_limit_s,
        None if pitches is None else tuple(pitches), yaws,
        None if args.zooms_hfov_deg is None else tuple(args.zooms_hfov_deg))


def run_plan_vantage(args: argparse.Namespace) -> int:
    if args.target_pd is None:
        raise ConfigError("--pattern vantage needs --target-pd (the P_D every required cell "
                          "must reach)")
    ROUTING.require("pdcov plan --pattern vantage needs")
    if args.altitudes_m and args.altitude_m is not None:
        raise ConfigError("give --altitude-m or --altitudes-m, not both")
    if args.zoom_hfov_deg is not None:
        raise ConfigError("--zoom-hfov-deg does not apply to the vantage pattern: give its "
                          "candidate zooms with --zooms-hfov-deg")
    alts = args.altitudes_m or [args.altitude_m or 10.0]
    mission = load_mission_warned(args.config, "plan")
    sc = scenario_of(mission, planning_overrides(args))
    settings = vantage_settings(args, args.target_pd,
                                1.0 if args.target_share is None else args.target_share,
                                alts, args.speed_mps)
    fleet = Fleet(args.vehicles or 1, args.max_flight_time_s)
    t0 = time.monotonic()
    m = plan_vantage_missions(sc, settings, fleet, args.gimbal_command or GimbalCommand.MANAGER,
                              args.routing_time_s or 2.0, args.hover_item or HoverItem.WAYPOINT)
    elapsed = time.monotonic() - t0
    with replacing_dir(args.out) as replaced:
        summary = write_vantage(args.out, mission, sc, m, elapsed, not args.no_figures)
    print(summary + _replaced_note(replaced, args.out))
    return 0


def _cover_doc(cover: Cover | None) -> dict[str, Any] | None:
    if cover is None:
        return None
    return {"points": len(cover.chosen), "cost": round(cover.cost, 4),
            "optimal": cover.optimal,
            "mip_gap": None if math.isnan(cover.mip_gap) else round(cover.mip_gap, 6)}


def _pointing_doc(aim: GimbalPointing | None, zoom_hfov_deg: float | None) -> dict[str, Any]:
    """A vantage point's gimbal pointing in vantage.json: pitch and earth-frame yaw (deg;
    yaw null: it follows the vehicle), nothing for a fixed mount; its zoom (deg), nothing
    unzoomed."""
    doc: dict[str, Any] = {} if zoom_hfov_deg is None else {"zoom_hfov_deg": zoom_hfov_deg}
    if aim is None:
        return doc
    return {"gimbal_pitch_deg": round(math.degrees(aim.pitch_rad), 3),
            "gimbal_yaw_deg": round(math.degrees(aim.yaw_rad), 3) if aim.earth_yaw else None,
            **doc}


def write_vantage(out: Path, mission: Mission, sc: Scenario, m: VantageMissions,
                  elapsed_s: float, figures: bool) -> str:
    """The mission files (plan.plan / plan.waypoints for one mission, else
    vehicle-V-sortie-S.plan / .waypoints each), vantage.json and the predicted evaluation of
    all missions together in ``out``; returns the summary text."""
    out.mkdir(parents=True, exist_ok=True)
    origin = mission.origin()
    names = []
    for vm in m.missions:
        r = vm.route
        stem = "plan" if len(m.missions) == 1 else f"vehicle-{r.vehicle}-sortie-{r.sortie}"
        write_plan(out / f"{stem}.plan", vm.prediction.plan, origin)
        write_plan(out / f"{stem}.waypoints", vm.prediction.plan, origin)
        names.append(stem)
    c = m.cover
    doc = {"candidates": c.n_candidates, "objective": str(c.objective),
           "greedy": _cover_doc(c.greedy), "exact": _cover_doc(c.exact),
           "greedy_gap": None if c.greedy_gap is None else round(c.greedy_gap, 4),
           "elapsed_s": round(elapsed_s, 2),
           "points": [{"x_enu_m": round(p.x_enu_m, 3), "y_enu_m": round(p.y_enu_m, 3),
                       "alt_agl_m": p.alt_agl_m, "hover_s": p.hover_s, "looks": p.looks,
                       **_pointing_doc(p.pointing, p.zoom_hfov_deg)}
                      for p in c.points],
           "missions": [{"file": f"{name}.plan", "vehicle": vm.route.vehicle,
                         "sortie": vm.route.sortie, "stops": list(vm.route.stops),
                         "flight_time_s": round(vm.flight_time_s, 1),
                         "routing_time_s": round(vm.route.time_s, 1),
                         "path_length_m": round(vm.prediction.flight.path_length_m, 1),
                         "waypoints": len(vm.prediction.plan.waypoints)}
                        for name, vm in zip(names, m.missions, strict=True)]}
    write_text_atomic(out / "vantage.json", json.dumps(doc, indent=2) + "\n")
    tracks = [vm.prediction.flight.r_body_enu[:, :2] for vm in m.missions]
    plans = [vm.prediction.plan.xy_enu_m for vm in m.missions]
    run = write_outputs(out, mission, m.grid, origin,
                        title=f"predicted: {len(c.points)} vantage points, "
                              f"{len(m.missions)} missions",
                        track_enu=np.vstack(tracks), plan_enu=np.vstack(plans),
                        extra_metrics={"vantage": doc}, figures=figures)
    gap = ("" if c.exact is None else
           f"; exact (HiGHS) {len(c.exact.chosen)} points, cost {c.exact.cost:.3f}"
           f"{'' if c.exact.optimal else ' (not proven optimal)'}, greedy gap "
           f"{c.greedy_gap:.1%}")
    pd = m.grid.pd[sc.mask]
    lines = [f"vantage: {len(c.points)} points of {c.n_candidates} candidates; greedy "
             f"{len(c.greedy.chosen)} points, cost {c.greedy.cost:.3f}{gap}",
             f"predicted share of free cells at the target: "
             f"{float((pd >= m.settings.target_pd).mean()):.3f}" if pd.size else "no free cells"]
    for name, vm in zip(names, m.missions, strict=True):
        lines.append(f"{name}: {len(vm.route.stops)} points, {vm.flight_time_s:.1f} s "
                     f"(take-off to landing), {vm.prediction.flight.path_length_m:.1f} m")
    return summary_text(run, lines)


def _replaced_note(replaced: bool, out: Path) -> str:
    return f"\nreplaced the previous outputs in {out}" if replaced else ""


def _score_row(s: Score) -> dict[str, Any]:
    p = s.params
    vantage = p.pattern == "vantage"
    return {"pattern": p.pattern, "altitude_m": p.alt_agl_m, "speed_mps": p.speed_mps,
            "heading_deg": None if vantage else round(math.degrees(p.heading_rad), 3),
            "overlap": None if p.spacing_m is not None or vantage else p.overlap,
            "spacing_m": None if vantage else round(s.spacing_m, 3),
            "proportion": round(s.proportion, 4),
            **({} if p.zoom_hfov_deg is None else {"zoom_hfov_deg": p.zoom_hfov_deg}),
            "mean_pd": round(s.mean_pd, 4), "flight_time_s": round(s.flight_time_s, 1),
            "path_length_m": round(s.path_length_m, 1), "missions": s.missions}


def _optimise_vantage(args: argparse.Namespace, alt_m: float, speed_mps: float
                      ) -> VantageSettings:
    """The vantage plan ``optimise`` scores at one altitude and speed: the target on
    --min-proportion of the cells, hovers of 2, 4 or 8 s, a 5 s ILP."""
    return VantageSettings(args.target_pd, (alt_m,), (2.0, 4.0, 8.0), args.min_proportion,
                           speed_mps=speed_mps, exact_time_limit_s=5.0)


def _table(rows: Sequence[dict[str, Any]]) -> str:
    keys = list(rows[0])
    cells = [[("" if r[k] is None else str(r[k])) for k in keys] for r in rows]
    widths = [max(len(k), *(len(c[i]) for c in cells)) for i, k in enumerate(keys)]
    lines = ["  ".join(k.rjust(w) for k, w in zip(keys, widths, strict=True))]
    lines += ["  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in cells]
    return "\n".join(lines)


def run_optimise(args: argparse.Namespace) -> int:
    mission = load_mission_warned(args.config, "optimise")
    sc = scenario_of(mission, planning_overrides(args))
    swept = [p for p in args.patterns if p != "vantage"]
    params = candidates(swept, args.altitudes_m, args.speeds_mps,
                        [math.radians(h) for h in args.headings_deg], args.spacings_m,
                        args.overlaps, args.zooms_hfov_deg or (None,))
    t0 = time.monotonic()
    scores, failures = (sweep(sc, params, args.target_pd, args.processes, progress=True)
                        if params else ([], []))
    if "vantage" in args.patterns:
        ROUTING.require("pdcov optimise --patterns vantage needs")
        for alt, v in itertools.product(args.altitudes_m, args.speeds_mps):
            try:
                scores.append(vantage_score(sc, _optimise_vantage(args, alt, v)))
            except ConfigError as exc:
                failures.append(f"vantage at {alt:g} m, {v:g} m/s: {exc}")
            params.append(PlanParams("vantage", alt, v))
    elapsed = time.monotonic() - t0
    for msg in failures:
        print(f"skipped: {msg}", file=sys.stderr)
    if not scores:
        raise ConfigError("optimise: no candidate plan could be built (see the messages "
                          "above)")
    front = pareto_front(scores)
    best = best_index(scores, args.min_proportion)
    out: Path = args.out
    with replacing_dir(out) as replaced:
        rows = [_score_row(s) for s in scores]
        for name, idx in (("candidates.csv", range(len(scores))), ("front.csv", front)):
            with atomic_write(out / name, "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=list(rows[0]) + ["on_front"])
                w.writeheader()
                for i in idx:
                    w.writerow({**rows[i], "on_front": i in front})
        _front_figure(out / "pareto.png", scores, front, best, args.target_pd)
        s = scores[best]
        if s.params.pattern == "vantage":
            t1 = time.monotonic()
            vm = plan_vantage_missions(sc, _optimise_vantage(args, s.params.alt_agl_m,
                                                             s.params.speed_mps))
            summary = write_vantage(out / "best", mission, sc, vm, time.monotonic() - t1, True)
            description = vm.missions[0].prediction.plan.description
        else:
            plan, spacing = build_plan(sc, with_spacing(s.params, s.spacing_m))
            pred = predict(sc, plan, s.params)
            summary = write_prediction(out / "best", mission, pred, pred.grid,
                                        f"best: {plan.description} at {s.params.alt_agl_m:g} m",
                                        spacing, terrain_warnings=terrain_warnings(sc, pred))
            description = plan.description
        write_text_atomic(out / "optimise.json", json.dumps({
            "target_pd": args.target_pd, "min_proportion": args.min_proportion,
            "candidates": len(params), "scored": len(scores), "elapsed_s": round(elapsed, 1),
            "front": [rows[i] for i in front], "best": rows[best]}, indent=2) + "\n")
    print(f"{len(scores)} plans in {elapsed:.1f} s "
          f"({60 * len(scores) / max(elapsed, 1e-9):.0f} plans/min); Pareto front of the "
          f"proportion of cells with P_D >= {args.target_pd:g} vs flight time:")
    print(_table([rows[i] for i in front]))
    reached = s.proportion >= args.min_proportion
    print(f"best ({'shortest flight reaching' if reached else 'none reaches'} "
          f"{args.min_proportion:g}): {description}, {s.params.alt_agl_m:g} m, "
          f"{s.params.speed_mps:g} m/s -> proportion {s.proportion:.3f}, "
          f"{s.flight_time_s:.0f} s")
    print(summary + _replaced_note(replaced, out))
    return 0


def _front_figure(path: Path, scores: Sequence[Score], front: Sequence[int], best: int,
                  target_pd: float) -> None:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: no pareto.png (pip install 'pdcov[plots]')",
              file=sys.stderr)
        return
    fig, ax = plt.subplots(figsize=(7, 5))
    for pat in sorted({s.params.pattern for s in scores}):
        sel = [s for s in scores if s.params.pattern == pat]
        ax.scatter([s.flight_time_s for s in sel], [s.proportion for s in sel], s=18,
                   alpha=0.6, label=pat)
    f = sorted(front, key=lambda i: scores[i].flight_time_s)
    ax.step([scores[i].flight_time_s for i in f], [scores[i].proportion for i in f],
            where="post", color="k", lw=1, label="Pareto front")
    ax.scatter([scores[best].flight_time_s], [scores[best].proportion], s=120,
               facecolors="none", edgecolors="r", label="best")
    ax.set_xlabel("predicted flight time (s)")
    ax.set_ylabel(f"proportion of cells with P_D >= {target_pd:g}")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run_refly(args: argparse.Namespace) -> int:
    mission = load_mission_warned(args.config, "refly")
    sc = scenario_of(mission, planning_overrides(args))
    flown = CoverageGrid.load_npz(args.grid, mission.camera, mission.detector,
                                  max_range_m=mission.max_range_m,
                                  min_revisit_s=mission.min_revisit_s,
                                  terrain=mission.terrain, exposure_s=mission.exposure_s)
    if flown.geometry != sc.geometry:
        raise ConfigError(f"{args.grid}: its grid {flown.geometry} is not the mission's "
                          f"{sc.geometry} (same domain and cell_size_m?)")
    settings = ReflySettings(args.target_pd, args.altitude_m, args.speed_mps, args.spacing_m,
                             _overlap(args), tuple(args.headings_deg))
    r = refly_of_grid(sc, flown, settings, tuple(args.start_enu_m), progress=True)
    spacing = settings.spacing_for(sc)
    flown.merge(r.prediction.grid)
    out: Path = args.out
    with replacing_dir(out) as replaced:
        summary = write_prediction(out, mission, r.prediction, flown,
                                    f"after the follow-up: {r.plan.description}", spacing,
                                    terrain_warnings=terrain_warnings(sc, r.prediction))
        write_text_atomic(out / "gaps.json", json.dumps({
            "target_pd": args.target_pd,
            "before": {"cells": r.gaps_before.n_cells,
                       "proportion": round(r.gaps_before.proportion, 4)},
            "after": {"cells": r.gaps_after.n_cells,
                      "proportion": round(r.gaps_after.proportion, 4)},
            "regions_enu_m": [np.round(np.asarray(p.exterior.coords), 2).tolist()
                              for p in r.gaps_before.regions],
            "compared": [{"description": o.description, "flight_time_s": round(o.flight_time_s, 1),
                          "path_length_m": round(o.path_length_m, 1), "gaps_after": o.gaps_after}
                         for o in r.compared]}, indent=2) + "\n")
    print(f"gaps below P_D {args.target_pd:g}: {r.gaps_before.n_cells} cells "
          f"({r.gaps_before.proportion:.1%}) before, {r.gaps_after.n_cells} "
          f"({r.gaps_after.proportion:.1%}) predicted after the follow-up")
    print("follow-ups compared (the shortest flight reaching the target is kept):")
    for o in r.compared:
        mark = "*" if o.description == r.plan.description else " "
        print(f" {mark} {o.flight_time_s:7.1f} s {o.path_length_m:8.1f} m  "
              f"{o.gaps_after:6d} gap cells after  {o.description}")
    print(summary + _replaced_note(replaced, out))
    return 0
