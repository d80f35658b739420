"""``pdcov refly``: the cells of a flown grid below the target P_D, and the follow-up flight
over them (docs/planning.md); writes its plan, the predicted evaluation after it and
gaps.json."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from pdcov.atomic import replacing_dir, write_text_atomic
from pdcov.commands.args import finite, output_dir, positive, probability
from pdcov.commands.mission_file import load_mission_warned
from pdcov.commands.plan_args import (
    firmware_args,
    planning_overrides,
    side_overlap,
    spacing_args,
    terrain_args,
)
from pdcov.commands.plan_output import replaced_note, terrain_warnings, write_prediction
from pdcov.core.grid import CoverageGrid
from pdcov.errors import ConfigError
from pdcov.planning.refly import ReflySettings, refly_of_grid
from pdcov.planning.scenario import scenario_of


def register(subparsers: argparse._SubParsersAction) -> None:
    r = subparsers.add_parser("refly", help="find cells below the target after a flight "
                                            "and plan a follow-up",
                              description="Gap finder and follow-up flight.")
    r.add_argument("--config", required=True, type=Path, help="mission config YAML")
    r.add_argument("--grid", required=True, type=Path, help="grid.npz of the flight so far")
    r.add_argument("--target-pd", type=probability, required=True,
                   help="P_D every free cell should reach; cells below it are gaps")
    r.add_argument("--altitude-m", type=positive, default=10.0, help="altitude above ground, m")
    r.add_argument("--speed-mps", type=positive, default=3.0, help="ground speed, m/s")
    spacing_args(r)
    r.add_argument("--headings-deg", nargs="+", type=finite, default=[0.0, 90.0],
                   help="track directions to try, deg clockwise from north")
    r.add_argument("--start-enu-m", type=finite, nargs=2, default=[0.0, 0.0],
                   metavar=("X", "Y"), help="where the follow-up starts (home: 0 0)")
    terrain_args(r)
    firmware_args(r)
    r.add_argument("--out", required=True, type=output_dir, help="folder to write")
    r.set_defaults(func=run_refly)

def run_refly(args: argparse.Namespace) -> int:
    mission = load_mission_warned(args.config, "refly")
    sc = scenario_of(mission, planning_overrides(args))
    cam = mission.first_camera  # the planner's (scenario_of)
    flown = CoverageGrid.load_npz(args.grid, cam.camera, cam.detector,
                                  max_range_m=mission.max_range_m,
                                  min_revisit_s=mission.min_revisit_s,
                                  terrain=mission.terrain, exposure_s=cam.exposure_s)
    if flown.geometry != sc.geometry:
        raise ConfigError(f"{args.grid}: its grid {flown.geometry} is not the mission's "
                          f"{sc.geometry} (same domain and cell_size_m?)")
    settings = ReflySettings(args.target_pd, args.altitude_m, args.speed_mps, args.spacing_m,
                             side_overlap(args), tuple(args.headings_deg))
    r = refly_of_grid(sc, flown, settings, tuple(args.start_enu_m), progress=True)
    spacing = settings.spacing_for(sc)
    flown.merge(r.prediction.grid)
    out: Path = args.out
    with replacing_dir(out) as replaced:
        summary = write_prediction(out, mission, r.prediction, flown,
                                    f"after the follow-up: {r.plan.description}", spacing,
                                    terrain_warnings=terrain_warnings(sc, r.prediction),
                                    firmware=args.firmware)
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
    print(summary + replaced_note(replaced, out))
    return 0
