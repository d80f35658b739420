"""What ``pdcov plan``, ``optimise`` and ``refly`` write of a predicted plan: the plan files
(.plan, .waypoints), the predicted evaluation and its summary, and the terrain warnings."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from pdcov.config.mission import Mission
from pdcov.core.blur import describe_blur
from pdcov.core.grid import CoverageGrid
from pdcov.core.mission import Firmware
from pdcov.planning.optimise import Prediction, Scenario
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


def replaced_note(replaced: bool, out: Path) -> str:
    """The summary's last line when the run replaced earlier outputs in ``out``."""
    return f"\nreplaced the previous outputs in {out}" if replaced else ""
