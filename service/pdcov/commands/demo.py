"""``pdcov demo``: the paper's scene, end to end, on the bundled example mission."""

from __future__ import annotations

import argparse
from importlib import resources
from pathlib import Path

from pdcov.config import load_mission


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo", help="plan, fly and evaluate the paper's 40 x 40 m scene",
        description="On the bundled example mission (the paper's 40 x 40 m square, 640 x 480 "
                    "camera at 5 frames/s, the ILLUSTRATIVE detector model): plan a "
                    "lawnmower and a spiral at 10 m, fly them kinematically, evaluate the "
                    "coverage of each and compare them, as in the paper's Figs. 7 and 8.")
    p.add_argument("--out", type=Path, default=Path("pdcov-demo"), help="output folder")
    p.add_argument("--altitude-m", type=float, default=10.0, help="flight height")
    p.add_argument("--speed-mps", type=float, default=5.0, help="flight speed")
    p.set_defaults(func=run_demo)


def run_demo(args: argparse.Namespace) -> int:
    from pdcov.commands.plan import scenario_of, write_prediction
    from pdcov.planning.optimise import PlanParams, build_plan, predict
    from pdcov.report.plots import compare_figure

    ref = resources.files("pdcov") / "data" / "demo_mission.yaml"
    with resources.as_file(ref) as path:
        mission = load_mission(path)
    print(f"pdcov demo: mission {ref.name} ({mission.vehicle_id}); detector model is "
          "ILLUSTRATIVE, not measured")
    scenario = scenario_of(mission)
    runs = []
    for pattern in ("lawnmower", "spiral"):
        params = PlanParams(pattern, args.altitude_m, args.speed_mps)
        plan, spacing = build_plan(scenario, params)
        pred = predict(scenario, plan, params)
        print()
        print(write_prediction(args.out / pattern, mission, pred, pred.grid,
                               f"{pattern} at {args.altitude_m:g} m, {args.speed_mps:g} m/s "
                               "(predicted)", spacing))
        runs.append((pattern, pred.grid.pd, pred.grid.mask))
    compare_figure(args.out / "compare.png", runs, mission.thresholds)
    print(f"\ncompare: {args.out / 'compare.png'}")
    return 0
