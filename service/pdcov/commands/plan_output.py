"""What ``pdcov plan``, ``optimise`` and ``refly`` write of a predicted plan: the plan files
(.plan, .waypoints, and its route as .gpx), the predicted evaluation and its summary, and
the terrain warnings."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pdcov.atomic import atomic_write
from pdcov.config.mission import Mission
from pdcov.core.blur import describe_blur
from pdcov.core.geodesy import enu_to_geodetic
from pdcov.core.grid import CoverageGrid
from pdcov.core.mission import Firmware
from pdcov.extras import GPX
from pdcov.planning.optimise import Prediction, Scenario
from pdcov.planning.plan import Plan
from pdcov.planning.plan_files import write_plan
from pdcov.planning.terrain_follow import clearance_intrusions, steep_legs
from pdcov.report.outputs import summary_text, write_outputs

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
                      terrain_warnings: Sequence[str] = (),
                      firmware: Firmware = Firmware.ARDUPILOT) -> str:
    """Plan files (for ``firmware``) and the predicted evaluation in ``out``; returns the
    summary text. The ``terrain_warnings`` (the function of that name) go to stderr and
    metrics.json."""
    for line in terrain_warnings:
        print(f"WARNING: terrain: {line}", file=sys.stderr)
    out.mkdir(parents=True, exist_ok=True)
    origin = mission.origin()
    write_plan(out / "plan.plan", pred.plan, origin, firmware)
    write_plan(out / "plan.waypoints", pred.plan, origin, firmware)
    route_missing = write_route(out / "plan.gpx", pred.plan, mission)
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
        "wrote plan.plan (QGroundControl), plan.waypoints (WPL 110)"
        + ("" if route_missing else " and plan.gpx (its route)") + f" in {out}",
        *([f"not written: plan.gpx: {route_missing}"] if route_missing else [])])


def write_route(path: Path, plan: Plan, mission: Mission) -> str | None:
    """``plan``'s waypoints as a GPX route at ``path`` (report/gpx.py): each at the ground
    point under it (as the .plan's relative and terrain frames place it), its elevation the
    origin's ground altitude plus its ENU height (m MSL; left out when the mission's ground
    altitude is unknown); None, or why it was not written (the gis extra missing)."""
    missing = GPX.message()
    if missing is not None:
        return missing
    from pdcov.report.gpx import route_document

    xyz = np.array([[w.x_enu_m, w.y_enu_m, w.z_enu_m] for w in plan.waypoints])
    origin = mission.origin()
    lla = enu_to_geodetic(np.c_[xyz[:, :2], np.zeros(len(xyz))], origin)
    lla[:, 2] = (np.nan if mission.ground_alt_msl_m is None
                 else origin.ground_alt_msl_m + xyz[:, 2])
    with atomic_write(path, "wb") as f:
        f.write(route_document(path.stem, plan.description, lla))
    return None


def replaced_note(replaced: bool, out: Path) -> str:
    """The summary's last line when the run replaced earlier outputs in ``out``."""
    return f"\nreplaced the previous outputs in {out}" if replaced else ""
