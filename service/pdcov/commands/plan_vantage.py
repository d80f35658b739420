"""``pdcov plan --pattern vantage`` (docs/planning.md "Vantage points"): its options, the
planned points and missions, and their files (the missions' plans, vantage.json and the
predicted evaluation)."""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.atomic import replacing_dir, write_text_atomic
from pdcov.commands.args import finite, nonnegative, positive, positive_int, probability
from pdcov.commands.mission_file import load_mission_warned
from pdcov.commands.plan_args import planning_overrides
from pdcov.commands.plan_output import replaced_note, write_route
from pdcov.config.mission import Mission
from pdcov.core.mission import Firmware, GimbalCommand, HoverItem
from pdcov.errors import ConfigError
from pdcov.extras import ROUTING
from pdcov.planning.cover import Cover
from pdcov.planning.optimise import Scenario
from pdcov.planning.plan import GimbalPointing
from pdcov.planning.plan_files import write_plan
from pdcov.planning.scenario import scenario_of
from pdcov.planning.tours import Fleet
from pdcov.planning.vantage import CoverObjective, VantageSettings, is_nadir
from pdcov.planning.vantage_missions import VantageMissions, plan_vantage_missions
from pdcov.report.outputs import summary_text, write_outputs


def vantage_args(p: argparse.ArgumentParser) -> None:
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


VANTAGE_FLAGS = ("target_pd", "target_share", "altitudes_m", "hover_s", "lattice_m",
                  "clearance_m", "objective", "ilp_time_limit_s", "vehicles",
                  "max_flight_time_s", "routing_time_s", "gimbal_command",
                  "gimbal_pitches_deg", "gimbal_yaws", "hover_item", "zooms_hfov_deg")
DEFAULT_GIMBAL_YAWS = 8
"""Earth-frame yaws per oblique pitch when --gimbal-pitches-deg names one."""


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
                              args.routing_time_s or 2.0, args.hover_item or HoverItem.WAYPOINT,
                              progress=True)
    elapsed = time.monotonic() - t0
    with replacing_dir(args.out) as replaced:
        summary = write_vantage(args.out, mission, sc, m, elapsed, not args.no_figures,
                                args.firmware)
    print(summary + replaced_note(replaced, args.out))
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
                  elapsed_s: float, figures: bool,
                  firmware: Firmware = Firmware.ARDUPILOT) -> str:
    """The mission files for ``firmware`` (plan.plan / plan.waypoints for one mission, else
    vehicle-V-sortie-S.plan / .waypoints each), vantage.json and the predicted evaluation of
    all missions together in ``out``; returns the summary text."""
    out.mkdir(parents=True, exist_ok=True)
    origin = mission.origin()
    names, route_missing = [], None
    for vm in m.missions:
        r = vm.route
        stem = "plan" if len(m.missions) == 1 else f"vehicle-{r.vehicle}-sortie-{r.sortie}"
        write_plan(out / f"{stem}.plan", vm.prediction.plan, origin, firmware)
        write_plan(out / f"{stem}.waypoints", vm.prediction.plan, origin, firmware)
        route_missing = write_route(out / f"{stem}.gpx", vm.prediction.plan, mission)
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
    if route_missing is not None:
        lines.append(f"not written: the missions' .gpx routes: {route_missing}")
    return summary_text(run, lines)
